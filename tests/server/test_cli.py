"""`chainsim serve` and `chainsim records user ...` from the command line, as the README shows them:
the sign-in page answers, /api/attempts without credentials is 401, a trainee's token cannot read
another trainee's attempt (403); accounts are made with one clear line per mistake; ``serve --base-url``
is the address xAPI identities use, over $CHAINSIM_SERVER_URL."""

from __future__ import annotations

import io
import sys

import pytest
from conftest import PASSWORD, attempt, call, populate, save_scored, start_server, upload

from chainsim.game.records import accounts
from chainsim.game.records.store import RecordStore


def add_user(cli, monkeypatch, db, *args, password=PASSWORD):
    monkeypatch.setattr(sys, "stdin", io.StringIO(password + "\n"))
    return cli("records", "--db", db, "user", "add", "--password-stdin", *args)


@pytest.mark.slow
def test_serve_acceptance(records_db, tmp_path, cli, monkeypatch):
    assert add_user(cli, monkeypatch, records_db, "--role", "trainer", "--class", "c1", "tina")[0] == 0
    assert add_user(cli, monkeypatch, records_db, "--role", "trainee", "--class", "c1", "alice")[0] == 0
    assert add_user(cli, monkeypatch, records_db, "--role", "trainee", "--class", "c1", "bob")[0] == 0
    code, out, _ = cli("records", "--db", records_db, "user", "token", "alice")
    alice = out.strip()
    code, out, _ = cli("records", "--db", records_db, "user", "token", "bob")
    bob = out.strip()
    server = start_server(records_db, tmp_path / "serve.log")
    try:
        status, page, _ = call(server, "GET", "/login")
        assert status == 200 and '<form method="post" action="/login"' in page
        assert call(server, "GET", "/api/attempts")[0] == 401
        bobs = save_scored(server, "bob", upload(), token=bob)["id"]
        assert call(server, "GET", f"/api/attempts/{bobs}", token=alice)[0] == 403
        assert call(server, "GET", f"/api/attempts/{bobs}", token=bob)[0] == 200
        # a new password revokes every token of the account
        monkeypatch.setattr(sys, "stdin", io.StringIO("another password\n"))
        assert cli("records", "--db", records_db, "user", "passwd", "--password-stdin", "bob")[0] == 0
        assert call(server, "GET", "/api/me", token=bob)[0] == 401
    finally:
        server.stop()
    code, out, _ = cli("records", "--db", records_db, "user", "list")
    assert code == 0 and "tina" in out and "trainer" in out and "alice" in out


def test_user_add_mistakes_are_one_line(tmp_path, cli, monkeypatch):
    db = tmp_path / "r.sqlite3"
    cases = [
        (("--role", "trainee", "--class", "c1", "--class", "c2", "zed"), "exactly one class"),
        (("--role", "trainer", "zed"), "at least one class"),
        (("--role", "trainee", "--class", "c1", "z" * 10_000), "characters"),
    ]
    for args, message in cases:
        code, _, err = add_user(cli, monkeypatch, db, *args)
        assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    code, _, err = add_user(cli, monkeypatch, db, "--role", "trainee", "--class", "c1", "zed", password="short")
    assert code == 2 and "at least 8" in err
    assert add_user(cli, monkeypatch, db, "--role", "trainee", "--class", "c1", "zed")[0] == 0
    code, _, err = add_user(cli, monkeypatch, db, "--role", "trainer", "--class", "c1", "zed")
    assert code == 2 and "already exists" in err
    monkeypatch.setattr(sys, "stdin", io.StringIO(""))
    code, _, err = cli("records", "--db", db, "user", "add", "--role", "trainee", "--class", "c1", "yan")
    assert code == 2 and "--password-stdin" in err
    code, _, err = cli("records", "--db", db, "user", "remove", "zed")
    assert code == 2 and "--yes" in err
    assert cli("records", "--db", db, "user", "remove", "zed", "--yes")[0] == 0
    with RecordStore(db) as store:
        assert accounts.list_users(store) == []
        assert store.list_trainees("c1")[0]["trainee"] == "zed"  # the records stay


def test_serve_refuses_bad_database_and_flags(tmp_path, cli):
    bad = tmp_path / "notes.sqlite3"
    bad.write_text("not a database")
    code, _, err = cli("serve", "--db", bad, "--port", "8123")
    assert code == 2 and "not an SQLite database" in err
    assert bad.read_text() == "not a database"
    code, _, err = cli("serve", "--port", "70000")
    assert code == 2 and "1-65535" in err
    code, _, err = cli("serve", "--db", tmp_path / "x.sqlite3", "--certfile", "c.pem")
    assert code == 2 and "go together" in err


def test_serve_base_url_names_the_programme_in_xapi_identities(records_db, tmp_path, monkeypatch):
    populate(records_db)
    with RecordStore(records_db) as store:
        store.save_attempt("c2", "carol", attempt(1))
    monkeypatch.setenv("CHAINSIM_SERVER_URL", "https://old.example.org")  # the flag wins over the variable
    server = start_server(records_db, tmp_path / "serve.log", args=("--base-url", "https://training.example.org/sim/"))
    try:
        token = call(server, "POST", "/api/login", {"name": "tom", "password": PASSWORD})[1]["token"]
        status, stmts, _ = call(server, "GET", "/export/attempts.xapi.json?class=c2", token=token)
        assert status == 200 and stmts
        assert all(s["actor"]["account"]["homePage"] == "https://training.example.org/sim" for s in stmts)
        assert "old.example.org" not in str(stmts) and "127.0.0.1" not in str(stmts)
    finally:
        server.stop()


def test_serve_refuses_a_bad_base_url_in_one_line(tmp_path, cli):
    for bad in ("training.example.org", "ftp://training.example.org", "https://u@training.example.org", "https://"):
        code, _, err = cli("serve", "--db", tmp_path / "x.sqlite3", "--base-url", bad)
        assert code == 2 and "--base-url" in err and "expected" in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "x.sqlite3").exists()

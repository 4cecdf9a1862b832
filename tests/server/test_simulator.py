"""The simulator saving to a records server: online, offline (queued, sent later), lost answers
(sent again, stored once), and the command line (`run --records`, `records login`, `records sync`).

Every save carries its recording and pack identity; the server acknowledges it with an upload id
and stores the attempt once its replay has scored it."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
from conftest import (
    PASSWORD,
    REPO,
    attempt,
    call,
    count_attempts,
    evidence,
    figures,
    populate,
    send,
    settle,
    start_server,
    wait_scored,
)
from records_db import free_port

from chainsim.components.hud import HudState
from chainsim.components.input_events import Widget
from chainsim.components.resources import PendingInput
from chainsim.game.packbuild.needle.make_prp_mouse_script import SCRIPTS
from chainsim.game.records import remote
from chainsim.game.records.store import RecordStore
from chainsim.game.trainer import windowform
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script


def play_and_save(settings: dict) -> list[str]:
    """Make the correct attempt as a person does at the window (clicks and drags at a person's pace), click
    Save, then press My attempts; the HUD messages and panel."""
    app = build_app("prp", settings=settings)
    try:
        events = windowform.gestures(app, load_script(SCRIPTS / "correct.toml"))
        events += windowform.save_click(app, events[-1][0])
        end = events[-1][0]
        app.resource(PendingInput).extend([*events, (end + 0.5, Widget("my_attempts"))])
        app.run_steps(int((end + 1.0) * 120))
        hud = app.resource(HudState)
        return [m[0] if isinstance(m, tuple) else str(m) for m in getattr(hud, "messages", [])] + list(hud.panel_text)
    finally:
        app.close()


def test_window_save_goes_to_the_server_and_my_attempts_lists_it(site, tmp_path):
    local = str(tmp_path / "local.sqlite3")
    with RecordStore(local) as store:
        assert remote.login(store, site.url, "alice", PASSWORD)["role"] == "trainee"
    settle(site.db)  # uploads earlier tests left are attempts by now: the count changes only by this one
    before = count_attempts(site.db)
    text = play_and_save({"db": local, "records": site.url, "class": "c1", "trainee": "alice"})
    assert any(line.startswith("Attempts of alice (c1):") for line in text)
    with RecordStore(local) as store:
        assert remote.pending(store) == []
        upload_id = store.query("SELECT remote_id FROM outbox")[0][0]
    result = wait_scored(site, upload_id, site.tokens["alice"])
    assert result["status"] == "scored", result
    assert count_attempts(site.db) == before + 1
    with RecordStore(site.db) as store:
        newest = store.list_attempts("c1", "alice")[-1]
    assert newest["id"] == result["attempt_id"]
    assert newest["target"] == "foramen_ovale_left" and newest["pack"] == "prp" and newest["differences"] == []


def test_save_message_names_the_signed_in_account_and_the_number_the_records_show(site, tmp_path):
    local = str(tmp_path / "local.sqlite3")
    with RecordStore(local) as store:
        remote.login(store, site.url, "bob", PASSWORD)
    # the names typed in the window are not the account's: the server files the attempt under bob in c1
    text = play_and_save({"db": local, "records": site.url, "class": "c9", "trainee": "zed"})
    (message,) = [line for line in text if "saved for" in line]
    assert "saved for bob in class c1" in message and "zed" not in message, message
    number = int(message.split("(number ")[1].split(" ")[0])
    with RecordStore(local) as store:
        upload_id = store.query("SELECT remote_id FROM outbox")[0][0]
    result = wait_scored(site, upload_id, site.tokens["bob"])
    with RecordStore(site.db) as store:
        ids = [a["id"] for a in store.list_attempts("c1", "bob")]
    assert ids.index(result["attempt_id"]) + 1 == number  # My attempts shows it with that number


@pytest.mark.slow
def test_offline_save_is_queued_then_synced_once(tmp_path, records_db):
    populate(records_db)
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    local = str(tmp_path / "local.sqlite3")
    server = start_server(records_db, tmp_path / "serve.log", port)
    with RecordStore(local) as store:
        remote.login(store, url, "bob", PASSWORD)
    server.stop()  # the server goes away before the trainee saves
    rr = remote.RemoteRecords(url, local)
    try:
        try:
            rr.save_attempt("c1", "bob", figures(), evidence())
            raise AssertionError("saved to a server that is down")
        except remote.KeptOffline as exc:
            assert "unreachable" in str(exc) and "records sync" in str(exc)
    finally:
        rr.close()
    with RecordStore(local) as store:
        assert len(remote.pending(store)) == 1
        result = remote.sync(store)
        assert result["sent"] == 0 and result["waiting"] == 1 and "unreachable" in result["problems"][0]
    server = start_server(records_db, tmp_path / "serve2.log", port)
    try:
        with RecordStore(local) as store:
            assert remote.sync(store) == {"sent": 1, "waiting": 0, "problems": []}
            assert remote.sync(store) == {"sent": 0, "waiting": 0, "problems": []}
            upload_id = store.query("SELECT remote_id FROM outbox")[0][0]
        token = call(server, "POST", "/api/login", {"name": "bob", "password": PASSWORD})[1]["token"]
        assert wait_scored(server, upload_id, token)["status"] == "scored"
        assert count_attempts(records_db) == 1
    finally:
        server.stop()


def test_lost_answer_is_sent_again_and_stored_once(site, tmp_path):
    local = str(tmp_path / "local.sqlite3")
    with RecordStore(local) as store:
        remote.login(store, site.url, "carol", PASSWORD)
        row_id = remote.enqueue(store, site.url, "c2", "carol", figures(), evidence())
        row = [r for r in remote.pending(store) if r["id"] == row_id][0]
        # the server took it but the answer never came back (the simulator crashed before marking)
        status, first, _ = send(site, "carol", json.loads(row["attempt"]), row["idem_key"])
        assert status == 202
        wait_scored(site, first["upload"], site.tokens["carol"])
        before = count_attempts(site.db)
        assert remote.sync(store)["sent"] == 1
        assert count_attempts(site.db) == before
        assert store.query("SELECT remote_id FROM outbox WHERE id = ?", (row_id,))[0][0] == first["upload"]


def test_refused_attempt_stays_in_the_queue_with_the_reason(site, tmp_path):
    local = str(tmp_path / "local.sqlite3")
    with RecordStore(local) as store:
        remote.login(store, site.url, "tina", PASSWORD)  # a trainer may not file for class c2
        remote.enqueue(store, site.url, "c2", "carol", attempt(1), evidence())
        result = remote.sync(store)
        assert result["sent"] == 0 and result["waiting"] == 1 and "403" in result["problems"][0]
        assert "teach" in store.query("SELECT last_error FROM outbox")[0][0]


def chainsim(*args, env=None, stdin=None):
    full = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""), **(env or {}))
    return subprocess.run(
        [sys.executable, "-m", "chainsim.game", *args],
        capture_output=True,
        text=True,
        env=full,
        input=stdin,
        timeout=300,
    )


@pytest.mark.slow
def test_command_line_run_login_and_sync(site, tmp_path):
    script = SCRIPTS / "correct-mouse.toml"  # the window's form, ending with Self assessment and Save
    local = str(tmp_path / "local.sqlite3")
    r = chainsim("records", "--db", local, "login", site.url, "alice", "--password-stdin", stdin="wrong password\n")
    assert r.returncode == 2 and "refused the sign-in" in r.stderr and "Traceback" not in r.stderr
    r = chainsim("records", "--db", local, "login", site.url, "alice", "--password-stdin", stdin=PASSWORD + "\n")
    assert r.returncode == 0, r.stderr
    settle(site.db)
    before = count_attempts(site.db)
    r = chainsim("run", "prp", "--steps", "720", "--input", str(script), "--db", local, "--records", site.url, "--json")
    assert r.returncode == 0, r.stderr
    with RecordStore(local) as store:
        upload_id = store.query("SELECT remote_id FROM outbox")[0][0]
    assert wait_scored(site, upload_id, site.tokens["alice"])["status"] == "scored"
    assert count_attempts(site.db) == before + 1
    r = chainsim("records", "--db", local, "sync")
    assert r.returncode == 0 and "sent 0 attempt(s); 0 waiting" in r.stdout
    r = chainsim("run", "prp", "--steps", "1", "--records", "ftp://nowhere", "--db", local)
    assert r.returncode == 2 and "http://127.0.0.1:8000" in r.stderr


def test_the_window_sign_in_asks_for_the_password_once_and_keeps_the_token(site, tmp_path):
    from chainsim.game.trainer.signin import SignInForm
    from chainsim.game.trainer.window import server_login

    local = str(tmp_path / "local.sqlite3")
    values = {"db": local, "records": site.url}
    login = server_login(values)
    assert login is not None  # no token yet: the form has a password field
    form = SignInForm({"class": "c1", "trainee": "alice"}, local, login=login)
    form.focus = "password"
    form.text("xyzzy-guess")
    form.key("return")
    assert not form.done and "refused" in form.error and form.values["password"] == ""
    assert "xyzzy" not in form.markdown()
    form.text(PASSWORD)
    assert PASSWORD not in form.markdown() and "*" * len(PASSWORD) in form.markdown()
    form.key("return")
    assert form.done and form.values["password"] == ""
    assert server_login(values) is None  # signed in: the next start asks only who is training

"""Saves that never fail silently, databases never written by mistake, output paths that fail in one line.

Permission cases run as the user nobody (root ignores file permissions, so as root they would prove
nothing).
"""

from __future__ import annotations

import hashlib
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from records_db import free_port

from chainsim.game.records.store import RecordStore
from chainsim.game.trainer.headless import build_app
from chainsim.systems.engine import meshgen
from chainsim.systems.engine.errors import UserError

from .conftest import ROOT, assert_one_line_error, chainsim

PRP_SCRIPT = ROOT / "assets" / "prp" / "scripts" / "correct.toml"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _foreign_sqlite(path: Path, *, version: int, table: str) -> Path:
    """Another program's database: one table of (id, owner) columns, at a given user_version."""
    con = sqlite3.connect(path)
    con.execute(f"CREATE TABLE {table} (id INTEGER, owner TEXT)")
    con.execute(f"INSERT INTO {table} (id, owner) VALUES (1, 'x')")
    con.execute(f"PRAGMA user_version = {version}")
    con.commit()
    con.close()
    return path


# -- saves ----------------------------------------------------------------------------------------


def test_a_headless_save_into_a_text_file_is_refused_before_the_run(cli, tmp_path):
    notes = tmp_path / "notes.txt"
    notes.write_text("my notes\n")
    code, out, err = cli("run", "prp", "--steps", "5", "--db", notes, "--out", tmp_path / "o")
    assert_one_line_error(code, err, "not an SQLite database")
    assert notes.read_text() == "my notes\n"
    assert not (tmp_path / "o" / "summary.json").exists()


def test_a_save_that_did_not_happen_ends_a_headless_run_with_exit_2(cli, tmp_path):
    script = tmp_path / "early-save.toml"
    script.write_text('format = 1\n[[event]]\nt = 0.1\nkind = "widget"\nname = "save"\n')
    db = tmp_path / "r.sqlite3"
    code, out, err = cli("run", "prp", "--steps", "30", "--input", script, "--db", db, "--out", tmp_path / "o")
    assert_one_line_error(code, err, "not saved", "landmarks")
    summary = (tmp_path / "o" / "summary.json").read_text()
    assert "save_errors" in summary  # what was computed is still written
    assert not db.exists()


def test_a_save_kept_offline_says_so_in_one_line(tmp_path):
    url = f"http://127.0.0.1:{free_port()}"  # nothing listens there
    script = ROOT / "assets" / "cutting" / "scripts" / "cut-and-open.toml"  # ends with Save attempt
    db = tmp_path / "r.sqlite3"
    r = chainsim("run", "cutting", "--input", script, "--records", url, "--db", db, env={"CHAINSIM_RECORDS_TOKEN": "t"})
    assert r.returncode == 0, r.stderr  # safe in the local queue: no failure
    said = [line.strip() for line in r.stdout.splitlines() if "this computer" in line or "sent to" in line]
    assert said == [f"attempt kept on this computer: {url} is unreachable; sent by `chainsim records sync`"]
    with RecordStore(db) as store:
        assert len(store.query("SELECT id FROM outbox WHERE sent_at IS NULL")) == 1


@pytest.mark.parametrize(
    "settings, words",
    [
        ({"trainee": "t" * 200}, "at most 64"),
        ({"class": ""}, "class name is empty"),
        ({"class": "   "}, "class name is empty"),
        ({"trainee": "bob\u202egnp.exe"}, "U+202E"),
        ({"trainee": "a\x00b"}, "U+0000"),
        ({"class": "c\u2028d"}, "U+2028"),
        ({"db": 42}, "must be str"),
        ({"procedure": "x"}, "unknown setting"),
    ],
)
def test_user_settings_are_checked_before_anything_runs(settings, words):
    with pytest.raises(UserError, match=words.replace("(", r"\(").replace("+", r"\+")):
        build_app("loop-demo", settings=settings)


def test_a_mistyped_database_folder_is_an_error_and_is_not_created(cli, tmp_path):
    db = tmp_path / "recrods" / "r.sqlite3"
    code, out, err = cli("run", "prp", "--steps", "5", "--db", db)
    assert_one_line_error(code, err, "does not exist", "mistyped")
    code, out, err = cli("records", "--db", db, "add-class", "c1")
    assert_one_line_error(code, err, "does not exist")
    assert not db.parent.exists()


def test_reading_records_never_creates_a_database(cli, tmp_path):
    db = tmp_path / "typo.sqlite3"
    for action in (["classes"], ["list"], ["show", "1"], ["trainees"]):
        code, out, err = cli("records", "--db", db, *action)
        assert_one_line_error(code, err, "no records database")
    assert not db.exists()


def test_a_new_database_is_announced(cli, tmp_path):
    db = tmp_path / "new.sqlite3"
    code, out, err = cli("records", "--db", db, "add-class", "c1")
    assert code == 0 and "created a new records database" in err and str(db) in err


@pytest.mark.parametrize("table", ["accounts", "classes"])  # another program's table; our name, other columns
@pytest.mark.parametrize("version", [0, 1, 2])
def test_another_programs_sqlite_file_is_never_written(table, version, cli, tmp_path):
    other = _foreign_sqlite(tmp_path / "app.db", version=version, table=table)
    before = _sha(other)
    for args in (
        ("run", "prp", "--steps", "5", "--db", other),
        ("records", "--db", other, "add-class", "c1"),
        ("records", "--db", other, "classes"),
    ):
        code, out, err = cli(*args)
        assert_one_line_error(code, err, "something else")
    assert _sha(other) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["app.db"]  # no -wal / -shm left beside it


def test_an_extra_view_or_trigger_marks_a_foreign_file(cli, tmp_path):
    db = tmp_path / "r.sqlite3"
    with RecordStore(db) as s:
        s.add_class("c1")
    con = sqlite3.connect(db)
    con.execute("CREATE VIEW everything AS SELECT * FROM classes")
    con.commit()
    con.close()
    code, out, err = cli("records", "--db", db, "add-class", "c2")
    assert_one_line_error(code, err, "something else", "'everything'")


def test_names_stored_with_hidden_characters_are_shown_escaped(cli, tmp_path):
    db = tmp_path / "r.sqlite3"
    with RecordStore(db) as s:
        s.add_class("c1")
    con = sqlite3.connect(db)  # as an older version, which did not refuse them, could have stored it
    con.execute("INSERT INTO trainees (class_id, name) VALUES (1, 'eve\u202egnp.exe')")
    con.commit()
    con.close()
    code, out, err = cli("records", "--db", db, "trainees")
    assert code == 0
    assert "\u202e" not in out and "eve\\u202egnp.exe" in out


def _protocol(*extras: str) -> str:
    """A protocol with one location trial per item of `extras` (extra keys of that trial)."""
    head = 'format = 1\npack = "prp"\n'
    return head + "".join(
        f'[[trial]]\nname = "t{i}"\ntask = "location"\ncondition = "c"\nscript = "{PRP_SCRIPT}"\n{extra}'
        for i, extra in enumerate(extras)
    )


@pytest.mark.parametrize(
    "text, args, words",
    [
        (_protocol("repeat = 9223372036854775807\n"), (), ("'repeat'", "1000")),
        (_protocol("steps = 100000000000\n"), (), ("'steps'", "1000000")),
        (_protocol(*["repeat = 1000\n"] * 11), (), ("11,000 runs", "10,000")),
        (_protocol(""), ("--trainee", "x" * 100), ("--trainee", "at most 64")),
        (_protocol(""), ("--class", ""), ("--class", "empty")),
    ],
)
def test_protocol_refuses_before_the_first_trial(text, args, words, cli, tmp_path):
    proto = tmp_path / "p.toml"
    proto.write_text(text)
    code, out, err = cli("protocol", proto, "--scripted", "--db", tmp_path / "r.sqlite3", *args)
    assert_one_line_error(code, err, *words)
    assert "[1/" not in err  # no trial ran
    assert not (tmp_path / "r.sqlite3").exists()


def test_protocol_with_a_mistyped_database_folder_runs_nothing(cli, tmp_path):
    proto = tmp_path / "p.toml"
    proto.write_text(_protocol(""))
    code, out, err = cli("protocol", proto, "--scripted", "--db", tmp_path / "nowhere" / "r.sqlite3")
    assert_one_line_error(code, err, "does not exist")
    assert "[1/" not in err


# -- output paths -----------------------------------------------------------------------------------


def test_output_paths_that_name_the_wrong_thing_are_one_line(cli, tmp_path):
    a_file = tmp_path / "a-file"
    a_file.write_text("keep")
    a_dir = tmp_path / "a-dir"
    a_dir.mkdir()
    db = tmp_path / "r.sqlite3"
    with RecordStore(db) as s:
        s.add_class("c1")
    for args, words in (
        (("run", "loop-demo", "--steps", "2", "--out", a_file), ("--out", "is a file")),
        (("run", "loop-demo", "--steps", "2", "--record", a_dir), ("--record", "is a folder")),
        (
            ("run", "loop-demo", "--steps", "2", "--record", tmp_path / "missing" / "r.json"),
            ("--record", "does not exist"),
        ),
        (("records", "--db", db, "export", "--csv", a_dir), ("is a directory",)),
        (("records", "--db", db, "export", "--csv", tmp_path / "missing" / "r.csv"), ("does not exist",)),
        (("bench", "chainmail", "--quick", "--parts", "thesis", "--out", a_file), ("--out", "cannot create folder")),
    ):
        code, out, err = cli(*args)
        assert_one_line_error(code, err, *words)
    assert a_file.read_text() == "keep"


def _read_only_folder(shared: Path) -> Path:
    ro = shared / "read-only"
    ro.mkdir()
    ro.chmod(0o555)
    return ro


def test_read_only_places_as_an_unprivileged_user(as_nobody, shared_tmp):
    ro = _read_only_folder(shared_tmp)
    mesh = shared_tmp / "g.npz"
    pos, links = meshgen.grid((3, 3))
    np.savez(mesh, positions=pos, links=links)
    mesh.chmod(0o644)
    db = shared_tmp / "r.sqlite3"  # a database nobody may read but not write
    with RecordStore(db) as s:
        s.add_class("c1")
    db.chmod(0o644)
    before = _sha(db)
    ok = shared_tmp / "ok"
    ok.mkdir()
    ok.chmod(0o777)
    dbw = ok / "w.sqlite3"  # a database nobody may use
    with RecordStore(dbw) as s:
        s.add_class("c1")
    dbw.chmod(0o666)
    cm = ["--alpha-min", "0.8", "--alpha-max", "1.2", "--beta", "0.1"]
    cases = [
        (("run", "loop-demo", "--steps", "2", "--out", ro / "o"), ("--out", "cannot create folder")),
        (("run", "loop-demo", "--steps", "2", "--out", ro), ("--out", "not writable")),
        (("run", "loop-demo", "--steps", "2", "--record", ro / "r.json"), ("--record", "not writable")),
        (("chainmail", mesh, "--grab", "0", "--to", "1", "1", *cm, "--out", ro / "x.npz"), ("--out", "not writable")),
        (("run", "prp", "--steps", "2", "--db", ro / "r.sqlite3"), ("not writable",)),
        (("records", "--db", ro / "r.sqlite3", "add-class", "c1"), ()),
        (("run", "prp", "--steps", "2", "--db", db), ("read-only",)),
        (("records", "--db", db, "add-class", "c2"), ()),
        (("records", "--db", dbw, "export", "--csv", ro / "r.csv"), ("cannot write",)),
    ]
    control = ("run", "loop-demo", "--steps", "2", "--out", ok / "run")
    results = as_nobody(*(args for args, _ in cases), control)
    for (args, words), (code, _out, err) in zip(cases, results):
        assert "Traceback" not in err, args
        assert_one_line_error(code, err, *words)
    code, out, err = results[-1]
    assert code == 0, err  # where nobody may write it works, so the failures above are the permissions
    assert (ok / "run" / "summary.json").stat().st_uid == 65534
    assert list(ro.iterdir()) == []
    assert _sha(db) == before


@pytest.mark.parametrize(
    "content",
    [
        '{"class": "c1", "trainee": "eve\\u202egnp.exe"}',  # a right-to-left override
        '{"class": "c1", "trainee": "' + "t" * 200 + '"}',  # too long
        "[" * 100000 + "]" * 100000,  # nested past the parser's stack
        '{"class": ["c1"], "trainee": 5}',  # wrong types
        "\x00\xff not json",
    ],
)
def test_a_damaged_remembered_sign_in_gives_empty_names(content, tmp_path, monkeypatch):
    from chainsim.game.trainer import signin

    monkeypatch.setattr(signin, "remembered_path", lambda: tmp_path / "signin.json")
    (tmp_path / "signin.json").write_text(content, encoding="utf-8", errors="surrogateescape")
    values = signin.remembered()
    assert values["trainee"] == ""
    assert values["class"] in ("", "c1")


def test_a_good_remembered_sign_in_is_kept(tmp_path, monkeypatch):
    from chainsim.game.trainer import signin

    monkeypatch.setattr(signin, "remembered_path", lambda: tmp_path / "signin.json")
    (tmp_path / "signin.json").write_text('{"class": "c1", "trainee": "Zoë"}', encoding="utf-8")
    assert signin.remembered() == {"class": "c1", "trainee": "Zoë"}

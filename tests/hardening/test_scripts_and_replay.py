"""Malformed input scripts and recordings, and replays without side effects.

Scripts and recordings are files anyone may hand over: nested 100000 deep, with times of 10^400,
NaN, coordinates of 1e308, settings of the wrong type. Each is refused in one line (exit 2) before
the run. A replay never writes records and never touches a path a recording names, so replaying a
session that pressed Save reaches the recorded digest and leaves every database as it was.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from chainsim.systems.engine import limits

from .conftest import ROOT, assert_one_line_error, chainsim

PRP_SCRIPT = ROOT / "assets" / "prp" / "scripts" / "correct.toml"


def _ev(**kw):
    return {"t": 0.5, "kind": "widget", "name": "x", **kw}


def _script(*events, **top):
    return json.dumps({"format": 1, "event": list(events), **top})


# id -> (file name, text, words the error names)
SCRIPTS: dict[str, tuple[str, str, tuple[str, ...]]] = {
    "json-100000-deep": ("s.json", "[" * 100000 + "]" * 100000, ("nested more than 32",)),
    "json-deep-objects": ("s.json", '{"a":' * 50000 + "1" + "}" * 50000, ("nested more than 32",)),
    "toml-5000-deep": ("s.toml", "format = 1\nx = " + "[" * 5000 + "]" * 5000 + "\n", ("nested more than 32",)),
    "t-10**400": ("s.json", _script(_ev()).replace('"t": 0.5', '"t": 1' + "0" * 400), ("64-bit",)),
    "t-1e400": ("s.json", _script(_ev()).replace('"t": 0.5', '"t": 1e400'), ("too large",)),
    "t-nan": ("s.json", _script(_ev()).replace('"t": 0.5', '"t": NaN'), ("NaN", "finite")),
    "t-infinity": ("s.json", _script(_ev()).replace('"t": 0.5', '"t": -Infinity'), ("Infinity",)),
    "t-negative": ("s.json", _script(_ev(t=-1)), ("'t'", "from 0")),
    "t-beyond-limit": ("s.json", _script(_ev(t=1e7)), ("'t'", "1e+06")),
    "t-text": ("s.json", _script(_ev(t="soon")), ("'t'",)),
    "t-out-of-order": ("s.json", _script(_ev(t=2.0), _ev(t=1.0)), ("time order",)),
    "mouse-x-1e308": ("s.json", _script({"t": 0, "kind": "mouse_move", "x": 1e308, "y": 0}), ("'x'", "1e+06")),
    "pick-point-1e308": (
        "s.json",
        _script({"t": 0, "kind": "pick", "entity": "table", "point": [1e308, 0, 0]}),
        ("'point'", "1e+06"),
    ),
    "pick-point-not-triple": (
        "s.json",
        _script({"t": 0, "kind": "pick", "entity": "table", "point": [1, 2]}),
        ("[x, y, z]",),
    ),
    "resize-10**30": ("s.json", _script({"t": 0, "kind": "resize", "width": 10**30, "height": 5}), ("64-bit",)),
    "resize-huge": ("s.json", _script({"t": 0, "kind": "resize", "width": 10**9, "height": 5}), ("'width'", "16384")),
    "widget-value-1e308": ("s.json", _script(_ev(value=1e308)), ("'value'", "1e+06")),
    "widget-name-empty": ("s.json", _script(_ev(name="")), ("'name'",)),
    "widget-name-5000": ("s.json", _script(_ev(name="w" * 5000)), ("'name'", "128")),
    "unknown-kind": ("s.json", _script({"t": 0, "kind": "teleport"}), ("unknown event kind",)),
    "not-utf8": ("s.json", "\udcff", ("not utf-8",)),
    "toml-syntax": ("s.toml", "format = = 1\n", ("TOML syntax error",)),
    "json-syntax": ("s.json", "{format: 1}", ("JSON syntax error",)),
    "format-2": ("s.json", json.dumps({"format": 2, "event": []}), ("'format' must be 1",)),
}


def _write(path: Path, text: str) -> Path:
    if text == "\udcff":
        path.write_bytes(b'{"format": 1, "x": "\xff"}')
    else:
        path.write_text(text)
    return path


@pytest.mark.parametrize("case", sorted(SCRIPTS))
def test_bad_input_script_is_one_line_before_the_run(case, cli, tmp_path):
    name, text, words = SCRIPTS[case]
    script = _write(tmp_path / name, text)
    code, out, err = cli("run", "loop-demo", "--steps", "5", "--input", script, "--out", tmp_path / "o")
    assert_one_line_error(code, err, *words)
    assert err.count("\n") == 1, err
    assert not (tmp_path / "o" / "summary.json").exists()


def test_a_deep_script_is_refused_without_a_hang(tmp_path):
    script = _write(tmp_path / "s.json", SCRIPTS["json-100000-deep"][1])
    r = chainsim("run", "loop-demo", "--steps", "5", "--input", script, timeout=60)
    assert_one_line_error(r.returncode, r.stderr, "nested")


def test_a_script_over_the_size_limit_is_refused_unread(cli, tmp_path, monkeypatch):
    monkeypatch.setattr(limits, "MAX_SCRIPT_BYTES", 1000)
    script = tmp_path / "big.json"
    script.write_text(_script(*[_ev(t=i * 0.01) for i in range(100)]))
    code, out, err = cli("run", "loop-demo", "--steps", "5", "--input", script)
    assert_one_line_error(code, err, "byte limit")


def test_too_many_events_are_refused(cli, tmp_path, monkeypatch):
    monkeypatch.setattr(limits, "MAX_EVENTS", 10)
    script = tmp_path / "many.json"
    script.write_text(_script(*[_ev(t=i * 0.01) for i in range(11)]))
    code, out, err = cli("run", "loop-demo", "--steps", "5", "--input", script)
    assert_one_line_error(code, err, "11 events", "limit")


# -- recordings ------------------------------------------------------------------------------------


@pytest.fixture
def recording(tmp_path, cli):
    """A valid loop-demo recording (as a dict) and where it was written."""
    rec = tmp_path / "rec.json"
    code, out, err = cli("run", "loop-demo", "--steps", "30", "--record", rec)
    assert code == 0, err
    return json.loads(rec.read_text())


BAD_FIELDS = {
    "dt-zero": ({"dt": 0}, ("'dt'",)),
    "dt-negative": ({"dt": -1}, ("'dt'",)),
    "dt-1e300": ({"dt": 1e300}, ("'dt'", "0.1")),
    "dt-text": ({"dt": "0.01"}, ("'dt'", "number")),
    "dt-true": ({"dt": True}, ("'dt'",)),
    "dt-null": ({"dt": None}, ("'dt'",)),
    "steps-negative": ({"steps": -1}, ("'steps'",)),
    "steps-2**63-1": ({"steps": 2**63 - 1}, ("'steps'", "1000000")),
    "steps-fraction": ({"steps": 1.5}, ("'steps'", "whole number")),
    "steps-text": ({"steps": "30"}, ("'steps'",)),
    "settings-text": ({"settings": "db=x"}, ("'settings'", "table")),
    "settings-db-number": ({"settings": {"db": 5}}, ("'db'", "text")),
    "settings-unknown": ({"settings": {"procedure": "evil"}}, ("unknown setting 'procedure'",)),
    "settings-trainee-list": ({"settings": {"trainee": ["a"]}}, ("'trainee'",)),
    "pack-missing": ({"pack": None}, ("'pack'",)),
    "pack-with-nul": ({"pack": "loop\u0000demo"}, ("'pack'",)),
    "not-a-recording": ({"chainsim": "script"}, ("not a chainsim recording",)),
    "event-time-inf-as-huge-int": ({"event": [{"t": 10**30, "kind": "key", "key": "a"}]}, ("64-bit",)),
}


@pytest.mark.parametrize("case", sorted(BAD_FIELDS))
def test_replay_of_a_bad_recording_is_refused_cleanly(case, recording, cli, tmp_path):
    change, words = BAD_FIELDS[case]
    data = {**recording, **change}
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    code, out, err = cli("replay", path, "--out", tmp_path / "ro")
    assert_one_line_error(code, err, *words)
    assert err.count("\n") == 1, err
    assert not (tmp_path / "ro").exists()


def test_replay_of_a_deep_recording_is_refused(tmp_path, cli):
    path = tmp_path / "deep.json"
    path.write_text('{"chainsim": "recording", "event": ' + "[" * 100000 + "]" * 100000 + "}")
    code, out, err = cli("replay", path)
    assert_one_line_error(code, err, "nested")


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_replaying_a_session_that_saved_writes_no_records_and_matches(tmp_path, cli):
    """The report's example: the replay wrote a new attempt and the digest then differed."""
    script = tmp_path / "save.toml"
    script.write_text(PRP_SCRIPT.read_text() + '\n[[event]]\nt = 4.7\nkind = "widget"\nname = "save"\n')
    db, rec = tmp_path / "records.sqlite3", tmp_path / "session.json"
    code, out, err = cli(
        "run", "prp", "--steps", "600", "--input", script, "--db", db, "--trainee", "ana", "--record", rec
    )
    assert code == 0, err
    assert "created a new records database" in err  # a new database is never created silently
    before = _digest(db)
    data = json.loads(rec.read_text())
    assert "db" not in data["settings"]  # the recorder's database is not written into the recording
    # a recording handed over by someone else names a database of its own choosing
    elsewhere = tmp_path / "settings.db"
    data["settings"]["db"] = str(elsewhere)
    rec.write_text(json.dumps(data))
    code, out, err = cli("replay", rec)
    assert code == 0, (out, err)
    assert "matches the recording" in out
    assert _digest(db) == before
    assert not elsewhere.exists()
    from chainsim.game.records.store import RecordStore

    with RecordStore(db) as store:
        assert len(store.list_attempts()) == 1

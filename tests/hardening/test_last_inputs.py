"""The last bad inputs of the hardening battery: each ends in one line naming what is wrong, exit 2,
no traceback (or, for a recording made from a folder path, a replay that reaches the same digest)."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import pytest

from chainsim.game.cli.main import COMMANDS, build_parser
from chainsim.game.packs import scaffold

from .conftest import ROOT, assert_one_line_error, chainsim


def _benches() -> list[str]:
    """Every `chainsim bench NAME` the parser knows (a new bench is checked without being listed here)."""
    sub = next(a for a in build_parser("bench")._actions if a.dest == "command").choices["bench"]
    return sorted(next(a for a in sub._actions if a.dest == "bench").choices)


BENCHES = _benches()
assert {"chainmail", "window", "models", "records", "train"} <= set(BENCHES), BENCHES


@pytest.mark.parametrize("argv", [[c, "--help"] for c in COMMANDS] + [["bench", b, "--help"] for b in BENCHES])
def test_every_help_page_prints(argv, cli):
    code, out, err = cli(*argv)
    assert code == 0, err
    assert "usage: chainsim" in out
    assert "Traceback" not in err


def test_a_percent_in_a_help_text_is_printed_as_written():
    parser = build_parser("bench")
    sub = next(a for a in parser._actions if a.dest == "command").choices["bench"]
    bench = next(a for a in sub._actions if a.dest == "bench")
    parser_help = bench.choices["models"].format_help()
    # a help text may keep argparse's own placeholders, and a lone % prints as one %
    listing = sub.format_help()
    assert "5 % of the reference" in listing
    assert "usage:" in parser_help


@pytest.mark.parametrize("path", ["/no/such/folder/for/chainsim", "./no-such-pack-folder", "assets/no-such-pack"])
def test_validate_of_a_missing_folder_names_the_folder(path, cli):
    code, _out, err = cli("validate", path)
    assert_one_line_error(code, err, path, "not found")
    assert "pack ''" not in err


def test_a_folder_without_a_manifest_is_said_so(tmp_path, cli):
    code, _out, err = cli("run", str(tmp_path), "--steps", "1")
    assert_one_line_error(code, err, str(tmp_path), "pack.toml")


def test_new_pack_into_a_read_only_folder_is_one_line(as_nobody, shared_tmp):
    ro = shared_tmp / "read-only"
    ro.mkdir()
    ro.chmod(0o555)
    [(code, _out, err)] = as_nobody(["new-pack", "mine", "--dir", ro])
    assert_one_line_error(code, err, str(ro), "cannot write")
    assert list(ro.iterdir()) == []


def test_new_pack_where_the_folder_cannot_be_written_leaves_nothing(tmp_path, monkeypatch, cli):
    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "mkdtemp", refuse)
    code, _out, err = cli("new-pack", "mine", "--dir", tmp_path)
    assert_one_line_error(code, err, str(tmp_path), "permission denied")
    assert list(tmp_path.iterdir()) == []


def test_new_pack_when_writing_fails_half_way_leaves_nothing(tmp_path, monkeypatch, cli):
    def full(self, *args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Path, "rename", full)
    code, _out, err = cli("new-pack", "mine", "--dir", tmp_path)
    assert_one_line_error(code, err, "mine", "no space left")
    assert list(tmp_path.iterdir()) == []


def test_new_pack_checks_access_before_writing(tmp_path, monkeypatch):
    monkeypatch.setattr(os, "access", lambda path, mode: False)
    with pytest.raises(scaffold.UserError, match="cannot write"):
        scaffold.create("mine", tmp_path)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("how", ["absolute", "relative", "scene"])
def test_a_recording_made_from_a_folder_path_replays(how, tmp_path, cli, monkeypatch):
    monkeypatch.chdir(ROOT)
    ref = {
        "absolute": str(ROOT / "assets" / "loop-demo"),
        "relative": "assets/loop-demo",
        "scene": "assets/prp/fluoro",
    }[how]
    rec = tmp_path / "r.json"
    code, _out, err = cli("run", ref, "--headless", "--steps", "40", "--record", rec, "--db", tmp_path / "r.sqlite3")
    assert code == 0, err
    recorded = json.loads(rec.read_text())
    code, out, err = cli("replay", rec)
    assert code == 0, err
    assert "matches the recording" in out
    assert f"scene {recorded['scene']}" in out


BAD_NUMBERS = {
    # file name -> (content, words the one line must hold)
    "nan.json": ('{"format": 1, "event": [{"t": 0.5, "kind": "widget", "name": "insert", "value": NaN}]}', "nan"),
    "inf.json": ('{"format": 1, "event": [{"t": 0.5, "kind": "widget", "name": "insert", "value": -Infinity}]}', "inf"),
    "big.json": (
        '{"format": 1, "event": [{"t": 0.5, "kind": "widget", "name": "insert", "value": 1}, '
        '{"t": 0.6, "kind": "widget", "name": "insert", "value": ' + "9" * 400 + "}]}",
        "400-digit",
    ),
    "huge-float.json": (
        '{"format": 1, "event": [{"t": 0.5, "kind": "widget", "name": "insert", "value": 1e400}]}',
        "too large",
    ),
    "nan.toml": ('format = 1\n[[event]]\nt = 0.5\nkind = "widget"\nname = "insert"\nvalue = nan\n', "nan"),
    "big.toml": (
        'format = 1\n[[event]]\nt = 0.5\nkind = "widget"\nname = "insert"\nvalue = 1\n'
        '[[event]]\nt = 0.6\nkind = "widget"\nname = "insert"\nvalue = ' + "9" * 400 + "\n",
        "400-digit",
    ),
}


@pytest.mark.parametrize("name", sorted(BAD_NUMBERS))
def test_a_bad_number_in_a_script_names_the_event_and_the_key(name, tmp_path, cli):
    content, word = BAD_NUMBERS[name]
    script = tmp_path / name
    script.write_text(content)
    event = "event 2" if "9" * 400 in content else "event 1"
    code, _out, err = cli("run", "loop-demo", "--headless", "--steps", "5", "--input", script)
    assert_one_line_error(code, err, name, event, "'value'", word)


def test_a_bad_number_in_a_recording_names_the_key(tmp_path):
    rec = tmp_path / "r.json"
    rec.write_text('{"chainsim": "recording", "format": 1, "pack": "loop-demo", "dt": Infinity, "event": []}')
    r = chainsim("replay", rec)
    assert_one_line_error(r.returncode, r.stderr, "'dt'", "infinity")

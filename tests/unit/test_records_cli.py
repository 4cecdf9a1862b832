"""`chainsim records`: tables, show, CSV export, delete guard, progress plot and exit codes."""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from chainsim.game.cli.commands import records as cmd
from chainsim.game.records.report import CSV_COLUMNS
from chainsim.game.records.store import ENV_VAR, RecordStore
from chainsim.game.records.validate import AIDS
from chainsim.systems.engine.errors import UserError

REPO = Path(__file__).resolve().parents[2]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def attempt(i: int, **over):
    a = {
        "pack": "prp",
        "created_at": f"2026-05-{10 + i:02d}T14:00:00Z",
        "duration_s": 90.0 - 5 * i,
        "landmark_error_mm": 6.0 - i,
        "needle_error_mm": 15.0 - 3 * i,
        "target": "foramen_ovale_left",
        "skull_contacts": 3 - i if i < 3 else 0,
        "path_length_mm": 70.0 + i,
        "aids": {"tip_view": True, "collision_signals": i == 0},
        "step_times": {"landmarks": 30.0, "insert": 60.0 - i},
        "details": {"D1": 0.5 * i, "d1": 0.1},
    }
    a.update(over)
    return a


@pytest.fixture
def db(records_db):  # an SQLite file and a PostgreSQL database (tests/records_db.py)
    path = records_db
    with RecordStore(path) as s:
        for i in range(4):
            s.save_attempt("c1", "alice", attempt(i))
        s.save_attempt("c1", "bob", attempt(0, needle_error_mm=None, target="skull"))
        s.save_attempt("c2", "alice", attempt(1))
        s.add_trainee("c2", "carol")
    return path


def call(db, *argv, env_db=False):
    parser = argparse.ArgumentParser(prog="chainsim")
    sub = parser.add_subparsers(dest="command", required=True)
    cmd.add_parser(sub)
    args = parser.parse_args(["records", *(() if env_db else ("--db", str(db))), *argv])
    return cmd.run(args)


def stored(db, *filters):
    with RecordStore(db) as s:
        return s.list_attempts(*filters)


def user_error(db, *argv) -> str:
    with pytest.raises(UserError) as e:
        call(db, *argv)
    msg = str(e.value)
    assert msg and "\n" not in msg and e.value.exit_code == 2
    return msg


def test_module_follows_command_convention():
    assert cmd.NAME == "records" and cmd.HELP and "\n" not in cmd.HELP


def test_classes_and_trainees_tables(db, capsys):
    assert call(db, "classes") == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split() == ["class", "trainees", "attempts"]
    assert [line.split() for line in out[2:]] == [["c1", "2", "5"], ["c2", "2", "1"]]
    assert call(db, "trainees", "--class", "c2") == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split() for line in out[2:]] == [["c2", "alice", "1"], ["c2", "carol", "0"]]


def test_list_is_an_aligned_table_of_the_selection(db, capsys):
    assert call(db, "list", "--class", "c1", "--trainee", "alice") == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:4] == ["id", "created_at", "class", "trainee"]
    body = lines[2:]
    assert len(body) == 4 and all(" alice " in line for line in body)
    # Right-aligned last column: every line ends at the same place, and columns line up.
    assert len({len(line) for line in lines}) == 1
    col = lines[0].index("landmark_mm") + len("landmark_mm")
    assert [line[col - 4 : col] for line in body] == ["6.00", "5.00", "4.00", "3.00"]
    assert call(db, "list", "--class", "c1", "--trainee", "bob") == 0
    bob = capsys.readouterr().out.splitlines()[2]
    assert bob[lines[0].index("needle_mm") : col + len("  needle_mm")].strip() == "-"


def test_show_prints_every_field(db, capsys):
    ids = [a["id"] for a in stored(db, "c1", "bob")]
    assert call(db, "show", str(ids[0])) == 0
    fields = dict(line.split(None, 1) for line in capsys.readouterr().out.splitlines())
    assert fields["trainee"] == "bob" and fields["needle_error_mm"] == "-" and fields["target"] == "skull"
    assert json.loads(fields["aids"])["collision_signals"] is True
    assert json.loads(fields["details"]) == {"D1": 0.0, "d1": 0.1}


@pytest.mark.parametrize("action", [["show", "999"], ["delete", "999", "--yes"], ["delete", "999"]])
def test_unknown_id_is_one_line_exit_2(db, action):
    assert "no attempt with id 999" in user_error(db, *action)


def test_unknown_class_or_trainee_is_one_line(db):
    assert "'c9'" in user_error(db, "list", "--class", "c9")
    assert "'zed'" in user_error(db, "list", "--class", "c1", "--trainee", "zed")
    assert "'c9'" in user_error(db, "trainees", "--class", "c9")


def test_delete_needs_yes(db, capsys):
    target = stored(db, "c1", "bob")[0]["id"]
    msg = user_error(db, "delete", str(target))
    assert "--yes" in msg and "bob" in msg
    assert target in [a["id"] for a in stored(db)]
    assert call(db, "delete", str(target), "--yes") == 0
    assert "deleted attempt" in capsys.readouterr().err
    remaining = [a["id"] for a in stored(db)]
    assert target not in remaining and len(remaining) == 5


def test_add_class_and_trainee(db, capsys):
    assert call(db, "add-class", "c3") == 0
    assert call(db, "add-trainee", "c4", "dave") == 0
    assert "new class" in capsys.readouterr().err
    assert "already exists" in user_error(db, "add-class", "c3")
    assert "already exists" in user_error(db, "add-trainee", "c4", "dave")
    assert "control character" in user_error(db, "add-class", "bad\x01name")
    with RecordStore(db) as s:
        assert s.list_classes() == ["c1", "c2", "c3", "c4"]


def test_export_csv_content(db, tmp_path, capsys):
    out = tmp_path / "out" / "alice.csv"
    out.parent.mkdir()
    out.write_text("old contents\n")
    assert call(db, "export", "--csv", str(out), "--trainee", "alice") == 0
    assert "wrote 5 attempt(s)" in capsys.readouterr().err
    with out.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    assert list(rows[0]) == list(CSV_COLUMNS)
    assert [(r["class_name"], r["trainee"]) for r in rows] == [("c1", "alice")] * 4 + [("c2", "alice")]
    first = rows[0]
    src = attempt(0)
    assert float(first["landmark_error_mm"]) == src["landmark_error_mm"]
    assert float(first["needle_error_mm"]) == src["needle_error_mm"]
    assert first["created_at"] == src["created_at"] and first["target"] == src["target"]
    assert int(first["skull_contacts"]) == src["skull_contacts"]
    assert {name: first[f"aid_{name}"] for name in AIDS} == {
        name: "1" if name in ("tip_view", "collision_signals") else "0" for name in AIDS
    }
    assert json.loads(first["step_times"]) == src["step_times"]
    assert json.loads(first["details"]) == src["details"]
    assert [p.name for p in out.parent.iterdir()] == ["alice.csv"]  # temp file renamed away


def test_export_neutralises_text_a_spreadsheet_would_run_as_a_formula(db, tmp_path):
    names = {'=HYPERLINK("http://x","y")': "c1", "+1+1": "c1", "-2+3": "c1", "@SUM(A1)": "c1"}
    with RecordStore(db) as s:
        for name, class_name in names.items():
            s.save_attempt(class_name, name, attempt(1))
        s.save_attempt("=cmd|' /c calc'!A0", "dave", attempt(2))
    out = tmp_path / "all.csv"
    assert call(db, "export", "--csv", str(out)) == 0
    with out.open(newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    trainees = {r["trainee"] for r in rows}
    assert {"'" + name for name in names} <= trainees and not any(t.startswith(("=", "+", "-", "@")) for t in trainees)
    assert "'=cmd|' /c calc'!A0" in {r["class_name"] for r in rows}
    # numbers stay numbers, and ordinary names are untouched
    assert {r["trainee"] for r in rows if r["class_name"] == "c1"} >= {"alice", "bob"}
    assert all(float(r["duration_s"]) > 0 for r in rows)


def test_export_no_contact_is_empty_cell(db, tmp_path):
    out = tmp_path / "bob.csv"
    call(db, "export", "--csv", str(out), "--class", "c1", "--trainee", "bob")
    with out.open(newline="") as fh:
        (row,) = list(csv.DictReader(fh))
    assert row["needle_error_mm"] == "" and row["target"] == "skull"


def test_failed_export_leaves_existing_file_alone(db, tmp_path):
    out = tmp_path / "keep.csv"
    out.write_text("precious\n")
    user_error(db, "export", "--csv", str(out), "--class", "nope")
    assert out.read_text() == "precious\n"
    assert "does not exist" in user_error(db, "export", "--csv", str(tmp_path / "no" / "x.csv"))


def _pixels(path: Path):
    from PIL import Image

    with Image.open(path) as im:
        return im.convert("RGB")


def _has_colour(img, rgb, tol=12) -> bool:
    import numpy as np

    px = np.asarray(img, dtype=np.int16)
    return bool((np.abs(px - np.array(rgb, dtype=np.int16)) <= tol).all(axis=-1).any())


def test_plot_writes_png_drawn_from_the_data(db, tmp_path, capsys):
    alice = tmp_path / "alice.png"
    bob = tmp_path / "bob.png"
    assert call(db, "plot", "--class", "c1", "--trainee", "alice", "--out", str(alice)) == 0
    assert "4 attempt(s)" in capsys.readouterr().err
    assert call(db, "plot", "--class", "c1", "--trainee", "bob", "--out", str(bob)) == 0
    for path in (alice, bob):
        data = path.read_bytes()
        assert data[:8] == PNG_MAGIC and len(data) > 1000
    red, blue = (214, 39, 40), (31, 119, 180)  # needle, landmark series colours
    a, b = _pixels(alice), _pixels(bob)
    assert _has_colour(a, blue) and _has_colour(a, red)
    # Bob's only attempt never touched anything: landmark point drawn, no needle series.
    assert _has_colour(b, blue) and not _has_colour(b, red)
    assert a.tobytes() != b.tobytes()


def test_plot_refuses_trainee_without_attempts(db, tmp_path):
    out = tmp_path / "carol.png"
    assert "no attempts" in user_error(db, "plot", "--class", "c2", "--trainee", "carol", "--out", str(out))
    assert not out.exists()
    assert ".png" in user_error(db, "plot", "--class", "c1", "--trainee", "alice", "--out", str(tmp_path / "a.jpg"))
    assert "'zed'" in user_error(db, "plot", "--class", "c1", "--trainee", "zed", "--out", str(out))


def test_db_flag_wins_over_env(db, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "env.sqlite3"))
    call(tmp_path / "env.sqlite3", "add-class", "from-env", env_db=True)
    capsys.readouterr()
    assert call(db, "classes") == 0
    assert "from-env" not in capsys.readouterr().out
    with RecordStore() as s:
        assert s.list_classes() == ["from-env"]


def test_bad_db_file_is_one_line_and_untouched(tmp_path):
    bad = tmp_path / "bad.sqlite3"
    bad.write_bytes(b"\x00\x01garbage" * 100)
    assert "not an SQLite database" in user_error(bad, "list")
    assert bad.read_bytes() == b"\x00\x01garbage" * 100


# -- through the real entry point -------------------------------------------------------------


def chainsim(*argv, env=None):
    full_env = dict(os.environ, PYTHONPATH=str(REPO), **(env or {}))
    return subprocess.run(
        [sys.executable, "-m", "chainsim.game", *argv], capture_output=True, text=True, cwd=REPO, env=full_env
    )


needs_cli = pytest.mark.skipif(not (REPO / "game" / "cli" / "main.py").exists(), reason="game/cli/main.py not present")


@pytest.mark.slow
@needs_cli
def test_entry_point_exit_codes(db, tmp_path):
    ok = chainsim("records", "--db", str(db), "list", "--class", "c2")
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.splitlines()[2].split()[2:4] == ["c2", "alice"]

    for argv, words in (
        (["show", "4242"], "no attempt with id 4242"),
        (["delete", "1"], "--yes"),
        (["list", "--class", "c9"], "'c9'"),
    ):
        r = chainsim("records", "--db", str(db), *argv)
        assert r.returncode == 2 and words in r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr

    bad = tmp_path / "notes.txt"
    bad.write_text("not a database\n")
    r = chainsim("records", "--db", str(bad), "classes")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert bad.read_text() == "not a database\n"

    r = chainsim("records", "classes", env={ENV_VAR: str(db)})
    assert r.returncode == 0 and "c1" in r.stdout


def test_db_flag_also_accepted_after_the_action(db, tmp_path, capsys):
    other = tmp_path / "other.sqlite3"
    # Given twice, the one after the action is the nearer and wins.
    assert call(other, "classes", "--db", str(db)) == 0
    assert [line.split()[0] for line in capsys.readouterr().out.splitlines()[2:]] == ["c1", "c2"]
    assert call(db, "add-class", "solo", "--db", str(other)) == 0
    with RecordStore(other) as s:
        assert s.list_classes() == ["solo"]

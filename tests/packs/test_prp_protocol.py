"""`chainsim protocol`: study mode of thesis 6.1.4 on the prp pack, and its refusals of bad protocols."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACK = Path(os.environ.get("CHAINSIM_PRP_TEST_PACK", ROOT / "assets" / "prp"))


def _write(tmp_path, text: str) -> Path:
    p = tmp_path / "proto.toml"
    p.write_text(text)
    return p


def test_protocol_runs_trials_saves_attempts_and_prints_table(cli, tmp_path):
    from chainsim.game.records.store import RecordStore

    proto = _write(
        tmp_path,
        f"""
format = 1
pack = "{PACK.as_posix()}"
[[trial]]
name = "loc"
task = "location"
condition = "reference_planes"
scripts = ["scripts/correct.toml", "scripts/variant-1.toml"]
[trial.aids]
reference_planes = true
[[trial]]
name = "ins"
task = "insertion"
condition = "without_clues"
script = "scripts/skull-hit.toml"
""",
    )
    db = tmp_path / "study.sqlite3"
    code, out, err = cli(
        "protocol", proto, "--scripted", "--db", db, "--class", "s1", "--trainee", "bot", "--out", tmp_path / "o"
    )
    assert code == 0, err
    assert "SCRIPTED" in out and "SCRIPTED" in err  # a smoke test says what it is
    assert "Location" in out and "Rotation and insertion" in out
    assert "3.2" in out and "44.0" in out  # the thesis's values beside ours
    assert "[3/3]" in err  # progress on stderr
    data = json.loads((tmp_path / "o" / "results.json").read_text())
    res = data["results"]
    assert [r["trial"] for r in res] == ["loc", "loc", "ins"]
    table = {(t["task"], t["condition"]): t for t in data["table"]}
    loc = table[("location", "reference_planes")]
    assert loc["mean_error_mm"] == pytest.approx((res[0]["error_mm"] + res[1]["error_mm"]) / 2)
    assert table[("insertion", "without_clues")]["mean_error_mm"] == pytest.approx(res[2]["error_mm"])
    assert (tmp_path / "o" / "table61.png").stat().st_size > 1000
    with RecordStore(db) as store:
        rows = store.list_attempts("s1", "bot")
    assert len(rows) == 3
    assert rows[0]["aids"]["reference_planes"] is True and rows[2]["aids"]["reference_planes"] is False
    assert rows[2]["target"] == "skull"
    assert rows[0]["details"]["protocol"]["condition"] == "reference_planes"
    assert rows[0]["details"]["protocol"]["scripted"] is True
    # scripted attempts never count as a participant's in the study's summary
    code, _, err = cli("protocol", proto, "--summary", "--db", db, "--class", "s1")
    assert code == 2 and "no attempts of study" in err


@pytest.mark.parametrize(
    "body,needle",
    [
        (
            'format = 1\npack = "prp"\ncolour = 1\n[[trial]]\ntask = "location"\ncondition = "x"\nscript = "a.toml"\n',
            "unknown key 'colour'",
        ),
        (
            'format = 1\npack = "prp"\n[[trial]]\ntask = "suturing"\ncondition = "x"\nscript = "a.toml"\n',
            "'task' must be one of",
        ),
        (
            'format = 1\npack = "prp"\n[[trial]]\ntask = "location"\ncondition = "x"\nscript = "a.toml"\n'
            "[trial.aids]\nxray = true\n",
            "unknown aid 'xray'",
        ),
        (
            'format = 1\npack = "prp"\n[[trial]]\ntask = "location"\ncondition = "x"\nscript = "a.toml"\nrepeat = 0\n',
            "'repeat' must be",
        ),
        ('format = 2\npack = "prp"\n', "'format' must be 1"),
        ('format = 1\npack = "prp"\n', "at least one [[trial]]"),
        (
            'format = 1\npack = "prp"\n[[trial]]\ntask = "location"\ncondition = "x"\nscirpt = "a.toml"\n',
            "unknown key 'scirpt'",
        ),
    ],
)
def test_bad_protocol_is_one_line_exit_2(cli, tmp_path, body, needle):
    db = tmp_path / "never.sqlite3"
    code, out, err = cli("protocol", _write(tmp_path, body), "--scripted", "--db", db)
    assert code == 2
    assert needle in err
    assert len(err.strip().splitlines()) == 1
    assert not db.exists()


def test_missing_protocol_file_is_one_line(cli, tmp_path):
    code, _, err = cli("protocol", tmp_path / "nope.toml")
    assert code == 2 and "not found" in err and len(err.strip().splitlines()) == 1


def test_missing_script_is_refused_before_anything_is_saved(cli, tmp_path):
    proto = _write(
        tmp_path,
        f'format = 1\npack = "{PACK.as_posix()}"\n[[trial]]\ntask = "location"\n'
        'condition = "x"\nscripts = ["scripts/correct.toml", "scripts/nope.toml"]\n',
    )
    db = tmp_path / "never.sqlite3"
    code, _, err = cli("protocol", proto, "--scripted", "--db", db)
    assert code == 2 and "nope.toml" in err
    assert not db.exists()

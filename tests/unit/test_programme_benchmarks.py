"""A programme's own benchmarks from its data: `chainsim study-report` writes benchmarks.toml beside
its report (programme data: who, when, which study), `--write-benchmarks PACK_DIR` sets them in a copy
of a pack (the old pack.toml kept, the pack still valid) and the debrief then says what they rest on;
a built-in pack and synthetic data are refused in one line (exit 2)."""

from __future__ import annotations

import shutil
import tomllib
from datetime import date
from pathlib import Path

import pytest
from test_validity_cli import FAST, fill

from chainsim.game.cli.commands.study_report import pack_metrics
from chainsim.game.packs.pack import load
from chainsim.game.study import cohort
from chainsim.game.study.programme_benchmarks import Proposal, edited
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures import verdicts as vd

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def prp():
    return pack_metrics("prp", [])


def study_db(tmp_path, prp) -> tuple[Path, Path]:
    """12 novices and 12 experts, far apart (people's attempts, groups on a register)."""
    pack, metrics = prp
    db_path = tmp_path / "study.sqlite3"
    drawn = cohort.build(metrics, 24, pack=pack, effect=3.0, trials=1, seed=3)
    fill(db_path, drawn, people=True)
    register = tmp_path / "register.csv"
    register.write_text(cohort.register_csv(cohort.people(drawn)))
    return db_path, register


def test_a_programme_sets_its_benchmarks_from_its_study_with_the_source_recorded(cli, tmp_path, prp):
    db_path, register = study_db(tmp_path, prp)
    copy = tmp_path / "our-prp"
    shutil.copytree(REPO / "assets" / "prp", copy)
    before = (copy / "pack.toml").read_text()
    out = tmp_path / "report"
    args = ("--db", db_path, "--groups", register, "--out", out, "--write-benchmarks", copy, *FAST)
    code, stdout, err = cli("study-report", "--pack", copy, *args)
    assert code == 0, err
    proposed = tomllib.loads((out / "benchmarks.toml").read_text())["metrics"]
    mark = proposed["landmark_error_mm"]
    assert mark["benchmark_basis"] == "programme"
    assert mark["benchmark_source"].startswith(f"programme data: 12 novices / 12 experts, {date.today()}, class study")
    assert "contrasting-groups pass mark, false pass" in mark["benchmark_source"]
    assert f"programme benchmarks into {copy / 'pack.toml'}" in stdout
    # the pack keeps every other key and its comments; the old text is kept beside it
    assert (copy / "pack.toml.bak").read_text() == before
    after = (copy / "pack.toml").read_text()
    assert [ln for ln in after.split("\n") if not ln.startswith("benchmark")] == [
        ln for ln in before.split("\n") if not ln.startswith("benchmark")
    ]
    assert "# -- what the assessment reports" in after
    assert cli("validate", copy)[0] == 0
    metrics = load(copy).section("metrics")
    for name, keys in proposed.items():
        assert {k: metrics[name][k] for k in keys} == keys
    # the debrief now says the programme's marks are not provisional; the rest still are
    rows = vd.verdicts(metrics, {})
    assert {r["basis"] for r in rows if r["name"] in proposed} == {"programme"}
    left = len([r for r in rows if r["basis"] == "provisional"])
    assert vd.basis_note(rows).startswith(f"Provisional: {left} of ") or left == 0


def test_a_built_in_pack_and_synthetic_data_are_never_written_into(cli, tmp_path, prp):
    db_path, register = study_db(tmp_path, prp)
    shipped = (REPO / "assets" / "prp" / "pack.toml").read_text()
    out = tmp_path / "r"
    code, _, err = cli(
        "study-report", "--pack", "prp", "--db", db_path, "--groups", register, "--out", out,
        "--write-benchmarks", REPO / "assets" / "prp", *FAST,
    )  # fmt: skip
    said = [line for line in err.splitlines() if line.startswith("chainsim study-report")]
    assert code == 2 and len(said) == 1 and "a built-in pack is never rewritten; copy the folder" in said[0]
    code, _, err = cli(
        "study-report", "--pack", "prp", "--demo-cohort", "12", "--out", out, "--write-benchmarks", tmp_path
    )
    assert code == 2 and "--write-benchmarks takes marks from people's attempts" in err
    code, _, err = cli("study-report", "--pack", "prp", "--db", db_path, "--out", out, "--write-benchmarks", tmp_path)
    assert code == 2 and "no pack.toml there; expected a pack folder" in err
    assert (REPO / "assets" / "prp" / "pack.toml").read_text() == shipped and not out.exists()


def test_synthetic_marks_are_written_as_provisional_beside_the_report(cli, tmp_path):
    out = tmp_path / "demo"
    code, _, err = cli("study-report", "--pack", "prp", "--demo-cohort", "12", "--trials", "2", "--out", out, *FAST)
    assert code == 0, err
    text = (out / "benchmarks.toml").read_text()
    assert "SYNTHETIC DATA: NOT EVIDENCE: these marks are provisional" in text
    # the report says what each of the pack's benchmarks rests on today
    assert "pack benchmark 3 mm (provisional; source: provisional: the scripted" in (out / "report.md").read_text()
    assert all(m["benchmark_basis"] == "provisional" for m in tomllib.loads(text).get("metrics", {}).values())


def test_the_edit_adds_missing_keys_and_refuses_what_it_cannot_edit_safely():
    text = '[metrics.a]\nlabel = "A"\n\n[metrics.b]\nlabel = "B"\nbenchmark = 1.0\n[docs.x]\ntitle = "x"\n'
    new = edited(text, [Proposal("b", 2.5, "programme", 'our "data"')])
    assert tomllib.loads(new)["metrics"]["b"] == {
        "label": "B",
        "benchmark": 2.5,
        "benchmark_basis": "programme",
        "benchmark_source": 'our "data"',
    }
    assert tomllib.loads(new)["metrics"]["a"] == {"label": "A"} and new.endswith('title = "x"\n')
    with pytest.raises(UserError, match=r"no \[metrics.c\] table"):
        edited(text, [Proposal("c", 1.0, "programme", "x")])
    with pytest.raises(UserError, match="multi-line string"):
        edited('[metrics.b]\nbenchmark_source = """a\nb"""\n', [Proposal("b", 1.0, "programme", "x")])

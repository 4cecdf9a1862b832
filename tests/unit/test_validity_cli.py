"""`chainsim study-report`: a register's problems one line each (exit 2), a report from a records database
with its groups from a register or from the attempts, and the synthetic label wherever a script or the
cohort builder made the data."""

from __future__ import annotations

import csv

import pytest

from chainsim.game.cli.commands.study_report import pack_metrics
from chainsim.game.records.store import RecordStore
from chainsim.game.study import cohort
from chainsim.game.study.validity_data import parse_register, select

FAST = ("--resamples", "1000")


@pytest.fixture(scope="module")
def prp():
    return pack_metrics("prp", [])


def people_like(record: dict) -> dict:
    """A cohort record as if a person had made it in a study: no scripted or synthetic mark, no group."""
    proto = dict(record["details"]["protocol"])
    for key in ("scripted", "synthetic", "group", "year_of_training", "procedures_performed"):
        proto.pop(key)
    return {**record, "details": {"protocol": proto}}


def fill(db, drawn, *, people: bool) -> None:
    with RecordStore(db) as store:
        for trainee, record in drawn:
            store.save_attempt("study", trainee, people_like(record) if people else record)


def test_every_bad_row_and_column_of_a_register_is_one_line_and_exit_2(cli, tmp_path):
    bad = tmp_path / "register.csv"
    bad.write_text(
        "participant,group,year_of_training,procedures_performed\n"
        "ann,novice,1,3\n"
        "bob,beginner,2,5\n"
        "cat,expert,five,200\n"
        "ann,expert,6,100\n"
        "dan,expert,7\n"
        "eve,expert,-3,1.5\n"
    )
    code, out, err = cli(
        "study-report", "--pack", "prp", "--groups", bad, "--db", tmp_path / "no.db", "--out", tmp_path
    )
    assert code == 2 and "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 5, err
    assert "line 3: participant 'bob': group is 'beginner'; expected novice or expert" in lines[0]
    assert "line 4: participant 'cat': year_of_training is 'five'; expected a whole number" in lines[1]
    assert "line 5: participant 'ann' is already on line 2" in lines[2]
    assert "line 6: 3 cells; the header has 4" in lines[3]
    assert (
        "line 7: participant 'eve': year_of_training is '-3'" in lines[4]
        and "procedures_performed is '1.5'" in lines[4]
    )
    assert all(str(bad) in line for line in lines)


def test_a_registers_missing_and_unknown_columns_are_named(cli, tmp_path):
    bad = tmp_path / "register.csv"
    bad.write_text("participant,grp,years\nann,novice,1\n")
    code, out, err = cli("study-report", "--pack", "prp", "--groups", bad, "--out", tmp_path / "o")
    assert code == 2
    lines = err.strip().splitlines()
    assert [line.split(": ", 2)[-1] for line in lines] == [
        "missing column 'group'",
        "missing column 'year_of_training'",
        "missing column 'procedures_performed'",
        "unknown column 'grp'; expected participant, group, year_of_training, procedures_performed",
        "unknown column 'years'; expected participant, group, year_of_training, procedures_performed",
    ]


def test_a_register_may_leave_experience_blank_and_write_groups_in_capitals():
    text = "\ufeffparticipant,group,year_of_training,procedures_performed\nann,Novice,,\nbob,EXPERT,6,120\n\n"
    reg = parse_register(text, "r.csv")
    assert reg["ann"].group == "novice" and reg["ann"].year_of_training is None
    assert reg["bob"].group == "expert" and reg["bob"].procedures_performed == 120


def test_report_from_a_database_with_a_register(cli, tmp_path, prp):
    pack, metrics = prp
    db = tmp_path / "study.sqlite3"
    drawn = cohort.build(metrics, 12, pack=pack, trials=2, seed=4, learning=1.0, trial_sd=0.3)
    fill(db, drawn, people=True)
    with RecordStore(db) as store:  # another pack's attempt, and a participant the register does not name
        store.save_attempt("study", "synthetic-01", {**people_like(drawn[0][1]), "pack": "elsewhere"})
        walk_in = people_like(drawn[0][1])
        walk_in["details"]["protocol"]["participant"] = "walk-in"
        store.save_attempt("study", "walk-in", walk_in)
    register = tmp_path / "register.csv"
    register.write_text(cohort.register_csv(cohort.people(drawn)) + "absent,expert,9,400\n")
    out = tmp_path / "report"
    code, stdout, err = cli("study-report", "--pack", "prp", "--db", db, "--groups", register, "--out", out, *FAST)
    assert code == 0, err
    md = (out / "report.md").read_text()
    assert "synthetic" not in md.lower()  # people's attempts: no label
    assert f"records database {db}, class study, pack {pack}" in md
    assert "Attempts used: 24 (24 local); participants: 6 novices, 6 experts (groups from a register)" in md
    assert "Left out: 1 attempts of another pack." in md and "Left out: 1 attempts by participants with no group" in md
    assert "Participants with attempts but no group: walk-in." in md and "without attempts: absent." in md
    rows = list(csv.DictReader((out / "statistics.csv").open()))
    assert [r["metric"] for r in rows] == list(metrics)
    assert all(r["novices"] == "6" and r["experts"] == "6" for r in rows)
    for name in metrics:
        assert (out / f"metric-{name}.png").stat().st_size > 5000
    assert (out / "learning-curves.png").stat().st_size > 5000
    assert stdout.strip().splitlines()[-2:] == [
        f"report: {out / 'report.md'}",
        f"benchmarks a programme may adopt: {out / 'benchmarks.toml'}",
    ]


def test_one_scripted_attempt_makes_the_report_say_synthetic_at_the_top(cli, tmp_path, prp):
    pack, metrics = prp
    db = tmp_path / "study.sqlite3"
    drawn = cohort.build(metrics, 8, pack=pack, seed=2)
    fill(db, drawn[1:], people=False)
    with RecordStore(db) as store:  # the first attempt once as a person's (but grouped), the rest scripted
        proto = dict(drawn[0][1]["details"]["protocol"])
        proto.pop("scripted"), proto.pop("synthetic")
        store.save_attempt("study", drawn[0][0], {**drawn[0][1], "details": {"protocol": proto}})
    code, stdout, err = cli("study-report", "--pack", "prp", "--db", db, "--out", tmp_path / "r", *FAST)
    assert code == 0, err
    first = (tmp_path / "r" / "report.md").read_text().splitlines()[0]
    assert first.startswith("**synthetic data: not evidence.**")
    assert "7 of the 8 attempts were made by an input script" in first
    assert stdout.startswith("SYNTHETIC DATA: NOT EVIDENCE")


def test_without_a_register_or_recorded_groups_the_command_asks_for_one(cli, tmp_path, prp):
    pack, metrics = prp
    db = tmp_path / "study.sqlite3"
    fill(db, cohort.build(metrics, 6, pack=pack, seed=1), people=True)
    code, out, err = cli("study-report", "--pack", "prp", "--db", db, "--out", tmp_path / "r")
    said = [line for line in err.splitlines() if line.startswith("chainsim study-report")]
    assert code == 2 and len(said) == 1 and said == err.splitlines()[-1:]
    assert "left out 6 by participants with no group" in said[0] and "give --groups FILE" in said[0]


def test_demo_cohort_writes_every_file_and_says_it_is_synthetic(cli, tmp_path, prp):
    _pack, metrics = prp
    out = tmp_path / "demo"
    code, stdout, err = cli(
        "study-report", "--pack", "prp", "--demo-cohort", "12", "--trials", "2", "--out", out, *FAST
    )
    assert code == 0, err
    files = {p.name for p in out.iterdir()}
    report = {"report.md", "statistics.csv", "learning-curves.png", "benchmarks.toml"}
    assert files == report | {f"metric-{m}.png" for m in metrics}
    md = (out / "report.md").read_text()
    assert md.startswith("**synthetic data: not evidence.**") and "synthetic cohort of 12 participants" in md
    code, _, err = cli("study-report", "--pack", "prp", "--demo-cohort", "12", "--db", tmp_path / "x.db", "--out", out)
    assert code == 2 and "--demo-cohort draws its own attempts" in err and err.count("\n") == 1


def test_selection_narrows_to_one_task_and_condition_and_leaves_out_retracted_attempts():
    metrics = {"m": {"label": "M"}}
    listed = cohort.as_listed(cohort.build(metrics, 6, pack="p", trials=4, seed=0))
    for i, a in enumerate(listed):
        a["details"]["protocol"].update(task="first" if i % 2 else "second", condition="plain")
    listed[1]["retracted_at"] = "2000-01-02T00:00:00+00:00"
    sel = select(listed, None, pack="p", task="first", condition="plain")
    assert sel.attempts == 11 and sel.left_out == {
        "of another task (or none)": 12,
        "retracted, or flagged and not accepted": 1,
    }
    assert all(a["details"]["protocol"]["task"] == "first" for own in sel.series.values() for a in own)
    assert sel.synthetic == 11 and len(sel.in_group("novice")) == len(sel.in_group("expert")) == 3
    assert select(listed, None, pack="p", condition="other").left_out == {"of another condition (or none)": 24}

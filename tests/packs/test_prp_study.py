"""A study session with people (thesis 6.1.4), driven through the same session object the window uses:
questionnaires typed with keys, trials with their aids locked, counterbalanced orders, Table 6.1 over
everyone in the records."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from chainsim.components.input_events import PickPoint, Widget
from chainsim.components.resources import PendingInput
from chainsim.game.cli.commands.protocol import load_protocol
from chainsim.game.records.store import RecordStore
from chainsim.game.study.protocol import latin_row
from chainsim.game.study.questionnaire import POST, PRE
from chainsim.game.study.session import StudySession, plan
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script
from chainsim.systems.view.ui.widgets import WidgetState

ROOT = Path(__file__).resolve().parents[2]
PACK = Path(os.environ.get("CHAINSIM_PRP_TEST_PACK", ROOT / "assets" / "prp"))

PROTO = f"""
format = 1
pack = "{PACK.as_posix()}"
title = "two tasks, two conditions each"

[[trial]]
name = "loc-planes"
task = "location"
condition = "reference_planes"
[trial.aids]
reference_planes = true

[[trial]]
name = "loc-none"
task = "location"
condition = "without_clues"

[[trial]]
name = "ins-viewer"
task = "insertion"
condition = "local_viewer"
[trial.aids]
tip_view = true
collision_signals = true

[[trial]]
name = "ins-none"
task = "insertion"
condition = "without_clues"
"""


def test_balanced_latin_rows_counterbalance_first_places_and_successions():
    for n in (2, 3, 4, 5):
        rows = [latin_row(n, p) for p in range(2 * n)]
        for row in rows:
            assert sorted(row) == list(range(n))
        # over 2n participants every condition comes first equally often, and each ordered pair of
        # neighbours occurs equally often
        firsts = [r[0] for r in rows]
        assert all(firsts.count(c) == 2 for c in range(n))
        pairs = [(r[i], r[i + 1]) for r in rows for i in range(n - 1)]
        counts = {p: pairs.count(p) for p in set(pairs)}
        assert len(set(counts.values())) == 1 and len(counts) == n * (n - 1)


class Participant:
    """A scripted person at the session: answers the forms with keys and does each trial."""

    def __init__(self, tmp_path, name, db):
        proto_file = tmp_path / "study61.toml"
        proto_file.write_text(PROTO)
        self.proto = load_protocol(proto_file)
        self.app = build_app(str(PACK), settings={"db": str(db), "class": "study", "trainee": name})
        self.s = StudySession(self.app, self.proto, name, "study", db)
        correct = load_script(PACK / "scripts" / "correct.toml")
        self.picks = [e for _, e in correct if isinstance(e, PickPoint)]
        self.aim = [e for _, e in correct if isinstance(e, Widget) and e.name.startswith(("rotate", "insert"))]

    def steps(self, seconds):
        for _ in range(int(seconds / self.app.time.dt)):
            self.app.update(self.app.time.dt)
            self.s.update()

    def answer(self, keys_and_text):
        for item in keys_and_text:
            if item.startswith("@"):
                self.s.key(item[1:])
            else:
                self.s.text(item)

    def do_trial(self):
        t = self.s.trials[self.s.k]
        self.s.key("return")  # the trial's page: go
        self.steps(0.3)
        ws = self.app.resource(WidgetState)
        locked = {a for a in t["aids"] if a in ws.disabled}
        now = self.app.time.sim_time
        pend = self.app.resource(PendingInput)
        events = []
        if t["task"] == "location":
            events += [(now + 0.1 * (k + 1), p) for k, p in enumerate(self.picks)]
        events += [(now + 0.5 + 0.05 * k, e) for k, e in enumerate(self.aim)]
        # the pack advances the needle at its insert_speed: time for it to reach the foramen
        events.append((now + 3.0, Widget("save", None)))
        pend.extend(events)
        self.steps(3.2)
        return t, locked


def test_a_participant_runs_the_session_and_everything_is_saved(tmp_path):
    db = tmp_path / "study.sqlite3"
    ann = Participant(tmp_path, "ann", db)
    ann.s.start()
    assert ann.s.state == "pre" and "Before the session" in ann.s.notice
    # the pre-session form: female, 34, nurse, computers very often, VR no, 3-D viewers yes
    ann.answer(["f", "@return", "34", "@return", "nurse", "@return", "@right", "@right", "@right", "@return"])
    ann.answer(["n", "@return", "y", "@return"])
    assert ann.s.state == "intro" and "Trial 1 of 4" in ann.s.notice
    done = []
    for _ in range(4):
        t, locked = ann.do_trial()
        done.append((t["task"], t["condition"]))
        assert locked == set(t["aids"])  # every aid set for the trial, and locked
    # participant 1: each task's conditions in protocol order
    assert done == [
        ("location", "reference_planes"),
        ("location", "without_clues"),
        ("insertion", "local_viewer"),
        ("insertion", "without_clues"),
    ]
    assert ann.s.state == "post"
    ratings = []
    for q in POST:
        if q.kind == "rating":
            ratings.append("9")
            ann.answer(["9", "@return"])
        else:
            ann.answer(["more x-ray", "@return"])
    assert ann.s.state == "summary"
    assert "Thesis Table 6.1" in ann.s.summary and "1 participants" in ann.s.summary
    with RecordStore(db) as store:
        rows = store.list_attempts("study", "ann")
        qs = store.list_questionnaires("study")
    assert len(rows) == 4
    proto = [r["details"]["protocol"] for r in rows]
    assert [p["order"] for p in proto] == [1, 2, 3, 4]
    assert {p["study"] for p in proto} == {"study61"} and all(not p.get("scripted") for p in proto)
    # landmarks placed by hand (location) or for the participant (insertion): errors are small here
    assert rows[0]["landmark_error_mm"] < 1.0 and rows[2]["target"] == "foramen_ovale_left"
    assert rows[0]["aids"]["reference_planes"] is True and rows[1]["aids"]["reference_planes"] is False
    assert rows[2]["aids"]["tip_view"] is True and rows[3]["aids"]["tip_view"] is False
    pre = next(q for q in qs if q["kind"] == "pre")["answers"]
    assert pre == {
        "sex": "female",
        "age": 34,
        "occupation": "nurse",
        "computer_use": "very often",
        "vr_simulation": "no",
        "viewer_3d": "yes",
    }
    post = next(q for q in qs if q["kind"] == "post")["answers"]
    assert post["local_viewer"] == 9 and post["improvements"] == "more x-ray"
    assert len(PRE) == len(pre)
    ann.s.key("return")
    assert ann.s.finished
    ann.app.close()


def test_the_next_participant_gets_the_other_order_and_the_table_covers_both(tmp_path):
    db = tmp_path / "study.sqlite3"
    orders = []
    for name in ("ann", "bob"):
        p = Participant(tmp_path, name, db)
        p.s.start()
        orders.append([(t["task"], t["condition"]) for t in p.s.trials])
        p.answer(["@return"] * len(PRE))  # questions may be left blank
        for _ in range(4):
            p.do_trial()
        p.answer(["@return"] * len(POST))
        assert p.s.state == "summary"
        summary, tab = p.s.summary, p.s.table
        p.app.close()
    assert orders[0] != orders[1]
    assert orders[1][:2] == [("location", "without_clues"), ("location", "reference_planes")]
    assert "2 participants" in summary
    cell = tab[("location", "reference_planes")]
    assert cell["participants"] == 2 and cell["attempts"] == 2 and cell["scored"] == 2
    with RecordStore(db) as store:
        qs = store.list_questionnaires("study")
    assert sorted((q["trainee"], q["kind"]) for q in qs) == [
        ("ann", "post"),
        ("ann", "pre"),
        ("bob", "post"),
        ("bob", "pre"),
    ]


def test_summary_command_prints_the_table_over_everyone(tmp_path, cli):
    db = tmp_path / "study.sqlite3"
    p = Participant(tmp_path, "ann", db)
    p.s.start()
    p.answer(["@return"] * len(PRE))
    for _ in range(4):
        p.do_trial()
    p.answer(["@return"] * len(POST))
    p.app.close()
    code, out, err = cli("protocol", tmp_path / "study61.toml", "--summary", "--db", db, "--out", tmp_path / "o")
    assert code == 0, err
    assert "1 participants" in out and "Thesis Table 6.1" in out
    assert (tmp_path / "o" / "table61.png").stat().st_size > 1000


def test_protocol_without_a_mode_says_what_to_choose(tmp_path, cli):
    f = tmp_path / "p.toml"
    f.write_text(PROTO)
    code, _, err = cli("protocol", f, "--db", tmp_path / "never.sqlite3")
    assert code == 2 and "--participant NAME" in err and "--scripted" in err
    assert not (tmp_path / "never.sqlite3").exists()


@pytest.mark.parametrize("participant", [0, 1, 2, 3])
def test_plan_cycles_through_conditions(tmp_path, participant):
    f = tmp_path / "p.toml"
    f.write_text(PROTO.replace('condition = "without_clues"\n', 'condition = "without_clues"\nrepeat = 2\n', 1))
    pl = plan(load_protocol(f), participant)
    loc = [t["condition"] for t in pl if t["task"] == "location"]
    # two cycles; the planes condition has repeat 1, so it appears once
    assert sorted(loc) == ["reference_planes", "without_clues", "without_clues"]
    assert [t["order"] for t in pl] == list(range(1, len(pl) + 1))


def test_a_participant_who_stopped_resumes_after_the_last_saved_trial(tmp_path):
    db = tmp_path / "study.sqlite3"
    ann = Participant(tmp_path, "ann", db)
    ann.s.start()
    ann.answer(["@return"] * len(PRE))
    ann.do_trial()
    ann.do_trial()
    # Esc in the middle of the third trial's page: the window asks first, saying what is kept
    question = ann.s.end_question()
    assert "2 of 4 trials are saved" in question and "continues with trial 3" in question
    ann.app.close()

    again = Participant(tmp_path, "ann", db)
    again.s.start()
    assert again.s.state == "resume" and "2 of 4 trials" in again.s.notice and "trial 3" in again.s.notice
    again.s.key("return")
    assert again.s.state == "intro" and "Trial 3 of 4" in again.s.notice  # no second pre-session form
    again.do_trial()
    again.do_trial()
    again.answer(["@return"] * len(POST))
    assert again.s.state == "summary"
    cell = again.s.table[("location", "reference_planes")]
    assert cell["attempts"] == 1  # each trial made and counted once
    with RecordStore(db) as store:
        orders = [r["details"]["protocol"]["order"] for r in store.list_attempts("study", "ann")]
    assert orders == [1, 2, 3, 4]
    again.app.close()


def test_restart_asks_and_then_retracts_the_saved_trials(tmp_path, cli, monkeypatch):
    import io

    db = tmp_path / "study.sqlite3"
    ann = Participant(tmp_path, "ann", db)
    ann.s.start()
    ann.answer(["@return"] * len(PRE))
    ann.do_trial()
    ann.app.close()
    args = ["protocol", tmp_path / "study61.toml", "--participant", "ann", "--db", db, "--restart"]
    args += ["--group", "novice", "--year-of-training", "2", "--procedures-performed", "0"]
    import chainsim.game.trainer.window as window

    sessions = []
    monkeypatch.setattr(window, "run_window", lambda args, session: sessions.append(session) or 0)
    monkeypatch.setattr("sys.stdin", io.StringIO("no\n"))
    code, _, err = cli(*args)
    assert code == 2 and "unchanged" in err and "Type yes" in err
    with RecordStore(db) as store:
        assert [r["retracted_at"] for r in store.list_attempts("study", "ann")] == [None]
    monkeypatch.setattr("sys.stdin", io.StringIO("yes\n"))
    code, out, err = cli(*args)
    assert code == 0, err
    with RecordStore(db) as store:
        assert store.list_attempts("study", "ann")[0]["retracted_at"]  # kept, marked, not counted
    fresh = Participant(tmp_path, "ann", db)
    fresh.s = sessions[-1](fresh.app)  # the session the window would run
    fresh.s.start()
    assert fresh.s.state == "pre" and len(fresh.s.trials) == 4  # from the start: questions, then trial 1
    fresh.app.close()


def test_restart_needs_a_participant(tmp_path, cli):
    f = tmp_path / "p.toml"
    f.write_text(PROTO)
    code, _, err = cli("protocol", f, "--scripted", "--restart", "--db", tmp_path / "x.sqlite3")
    assert code == 2 and "--participant" in err


def test_summary_shows_every_condition_of_the_protocol_those_without_attempts_too(tmp_path, cli):
    db = tmp_path / "study.sqlite3"
    p = Participant(tmp_path, "ann", db)
    p.s.start()
    p.answer(["@return"] * len(PRE))
    p.do_trial()  # only the first location trial is saved
    p.app.close()
    code, out, err = cli("protocol", tmp_path / "study61.toml", "--summary", "--db", db)
    assert code == 0, err
    header = out.splitlines()[2]
    for condition in ("reference planes", "without clues", "local viewer"):
        assert condition in header
    assert "0/0" in out.splitlines()[4]  # the conditions still missing: none scored of none made


SERVER_ALLOCATION = {
    "by": "records server http://records.example",
    "design": "balanced Latin square",
    "slot": 1,
    "group": "expert",
    "year_of_training": 5,
    "procedures_performed": 40,
}


def test_practice_trials_come_first_are_saved_marked_and_never_counted(tmp_path):
    """`practice = 1`: one practice trial before each task's scored ones, in the order the register's slot
    gives; each trial keeps its recording and the participant's covariates; the table counts no practice."""
    from chainsim.game.records import provenance

    db = tmp_path / "study.sqlite3"
    ann = Participant(tmp_path, "ann", db)
    ann.proto["practice"] = 1
    ann.s = StudySession(ann.app, ann.proto, "ann", "study", db, allocation=SERVER_ALLOCATION)
    ann.s.start()
    assert "Warning" not in ann.s.notice  # the order comes from the server's sequence
    ann.answer(["@return"] * len(PRE))
    assert "Practice trial (not scored) 1 of 6" in ann.s.notice
    done = [ann.do_trial()[0] for _ in range(6)]
    assert [t["practice"] for t in done] == [True, False, False, True, False, False]
    # slot 1: the second row of the design, so each task starts with its second condition
    assert [t["condition"] for t in done[:3]] == ["without_clues", "without_clues", "reference_planes"]
    ann.answer(["@return"] * len(POST))
    assert ann.s.table[("location", "without_clues")]["attempts"] == 1
    with RecordStore(db) as store:
        rows = store.list_attempts("study", "ann")
        recordings = [store.recording(r["id"]) for r in rows]
    protos = [r["details"]["protocol"] for r in rows]
    assert [p["practice"] for p in protos] == [True, False, False, True, False, False]
    assert {(p["group"], p["year_of_training"], p["procedures_performed"]) for p in protos} == {("expert", 5, 40)}
    assert {p["allocation"]["slot"] for p in protos} == {1} and "warning" not in protos[0]["allocation"]
    events = [len(provenance.decode_recording(text)["event"]) for text in recordings]
    assert all(n > 0 for n in events) and events == sorted(events)  # each trial's session so far, kept
    ann.app.close()


def test_without_a_records_server_the_order_is_local_and_every_trial_says_so(tmp_path, cli):
    db = tmp_path / "study.sqlite3"
    ann = Participant(tmp_path, "ann", db)
    ann.s.start()
    assert "Warning" in ann.s.notice and "another machine may give the same order" in ann.s.notice
    ann.answer(["@return"] * len(PRE))
    assert "another machine may give the same order" in ann.s.notice
    ann.do_trial()
    ann.app.close()
    with RecordStore(db) as store:
        (row,) = store.list_attempts("study", "ann")
    assert "another machine may give the same order" in row["details"]["protocol"]["allocation"]["warning"]
    code, out, err = cli("protocol", tmp_path / "study61.toml", "--summary", "--db", db)
    assert code == 0, err
    assert "1 trial(s) took their condition order from one machine's own register" in out


def test_register_enters_participants_in_order_and_refuses_bad_entries(tmp_path, cli):
    f = tmp_path / "study61.toml"
    f.write_text(PROTO.replace("title =", "practice = 1\ntitle =", 1))
    db = tmp_path / "study.sqlite3"
    entry = ["--group", "novice", "--year-of-training", "2", "--procedures-performed", "3"]
    code, out, err = cli("protocol", f, "--register", "ann", *entry, "--db", db)
    assert code == 0, err
    assert "slot 0" in out and "practice loc-planes, loc-planes, loc-none" in out
    assert "another machine may give the same order" in err
    code, out, _ = cli("protocol", f, "--register", "bob", *entry, "--db", db)
    assert code == 0 and "slot 1" in out and "practice loc-none, loc-none, loc-planes" in out
    code, _, err = cli(
        "protocol", f, "--register", "cy", *entry[:2], "--year-of-training", "two", *entry[4:], "--db", db
    )
    assert code == 2 and "year_of_training is 'two'; expected a whole number from 0 to 80" in err
    assert len(err.strip().splitlines()) == 1
    code, _, err = cli("protocol", f, "--register", "ann", *entry[:4], "--procedures-performed", "9", "--db", db)
    assert code == 2 and "already in the register" in err
    code, _, err = cli("protocol", f, "--participant", "dee", "--db", db)
    assert code == 2 and "not in the register of study 'study61'" in err and "--year-of-training" in err
    code, _, err = cli("protocol", f, "--register", "eve", "--group", "expert", "--db", db)
    assert code == 2 and "--year-of-training is missing" in err

"""A study's trials filed on the records server (chainsim protocol --records), on SQLite and PostgreSQL.

A participant registered on the server runs the protocol at the window; every trial is kept in the
local records and filed on the server, which checks it against the study's design and the participant's
allocation, replays it (the aids and points the session set accepted as the protocol's), keeps
details.protocol from the replay and marks practice trials; Table 6.1 read from the server counts the
scored trials. A trial whose aids or condition are not its allocation's is refused in one line."""

from __future__ import annotations

import copy
import uuid

from conftest import SCRIPTS, call, upload, wait_scored

PROTOCOL = """format = 1
pack = "prp"
practice = 1
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
"""
ENTRY = ["--group", "novice", "--year-of-training", "2", "--procedures-performed", "3", "--class", "c1"]


def run_session(session, app) -> list[dict]:
    """The participant at the window: the pages answered with keys, each trial done with clicks at a
    person's pace (chainsim.game.trainer.windowform), Save clicked; the trials in the order given."""
    from chainsim.components.hud import HudState
    from chainsim.components.input_events import PickPoint, Widget
    from chainsim.components.resources import PendingInput
    from chainsim.game.study.questionnaire import POST, PRE
    from chainsim.game.trainer import windowform
    from chainsim.game.trainer.inputscript import load_script

    correct = load_script(SCRIPTS / "correct.toml")
    picks = [e for _, e in correct if isinstance(e, PickPoint)]
    aim = [e for _, e in correct if isinstance(e, Widget) and e.name.startswith(("rotate", "insert"))]

    def steps(seconds: float) -> None:
        for _ in range(int(seconds / app.time.dt)):
            app.update(app.time.dt)
            session.update()

    session.start()
    for _ in PRE:
        session.key("return")
    done = []
    while session.state == "intro":
        t = session.trials[session.k]
        session.key("return")
        steps(0.3)
        now = app.time.sim_time
        script = [(now + 0.1 * (k + 1), p) for k, p in enumerate(picks)] if t["task"] == "location" else []
        # a click on the locked aid's button: ignored at the window, and so in the server's replay
        script.insert(0, (now, Widget("reference_planes", not t["aids"]["reference_planes"])))
        script += [(now + 0.5 + 0.05 * k, e) for k, e in enumerate(aim)] if t["task"] == "insertion" else []
        events = windowform.gestures(app, script, close_page=False)
        events += windowform.save_click(app, max(e[0] for e in events))
        app.resource(PendingInput).extend(events)
        k = session.k
        for _ in range(80):  # the needle reaches its target at the pack's insert_speed, then Save
            steps(0.25)
            if session.k != k or session.state != "trial":
                break
        assert session.k == k + 1, f"trial {k + 1} was not saved: {app.resource(HudState).messages}"
        done.append(t)
    for _ in POST:
        session.key("return")
    return done


def test_trials_are_filed_checked_replayed_and_tabled(site, tmp_path, cli, monkeypatch):
    import chainsim.game.trainer.window as window
    from chainsim.game.records import remote
    from chainsim.game.records.store import RecordStore
    from chainsim.game.trainer.headless import build_app

    study = f"s{uuid.uuid4().hex[:8]}"
    proto = tmp_path / f"{study}.toml"
    proto.write_text(PROTOCOL)
    tina = site.tokens["tina"]
    monkeypatch.setenv("CHAINSIM_RECORDS_TOKEN", tina)
    db = tmp_path / "local.sqlite3"
    common = ["--records", site.url, "--db", db]
    rc, out, err = cli("protocol", proto, "--register", "P1", *ENTRY, *common)
    assert rc == 0 and "slot 0" in out, err
    sessions = []
    monkeypatch.setattr(window, "run_window", lambda args, session: sessions.append(session) or 0)
    assert cli("protocol", proto, "--participant", "P1", *common, "--class", "c1")[0] == 0
    app = build_app("prp", settings={"db": str(db), "class": "c1", "trainee": "P1"})
    try:
        session = sessions[-1](app)
        done = run_session(session, app)
    finally:
        app.close()
    assert [(t["name"], t["practice"]) for t in done] == [
        ("loc-planes", True),
        ("loc-planes", False),
        ("loc-none", False),
        ("ins-viewer", True),
        ("ins-viewer", False),
    ]
    with RecordStore(db) as store:
        local = store.list_attempts("c1", "P1")  # the local copy, as without a server
        rows = remote.pending(store)
        sent = store.query("SELECT remote_id FROM outbox WHERE server = ? ORDER BY id", (site.url,))
    assert len(local) == 5 and rows == []
    stored = []
    for row in sent:
        result = wait_scored(site, row["remote_id"], tina)
        assert result["status"] == "scored", result
        status, attempt, _ = call(site, "GET", f"/api/attempts/{result['attempt_id']}", token=tina)
        assert status == 200
        stored.append(attempt)
    protos = [a["details"]["protocol"] for a in stored]
    assert [(p["trial"], p["practice"], p["order"]) for p in protos] == [
        (t["name"], t["practice"], k) for k, t in enumerate(done, 1)
    ]
    assert all(p["allocation"]["slot"] == 0 and p["group"] == "novice" for p in protos)
    assert stored[4]["aids"]["tip_view"] and not stored[2]["aids"]["reference_planes"]
    assert [a["differences"] for a in stored] == [[]] * 5  # the replays computed what the session showed
    assert {a["source"] for a in stored} == {"replayed"}

    rc, out, err = cli("protocol", proto, "--summary", *common, "--class", "c1")
    assert rc == 0, err
    assert "2 practice trial(s) left out of the table" in out and "1 participants" in out
    assert out.count("1/1") == 3  # each condition: its one scored trial, the practice ones not counted

    # the same trial, its aids changed: the server's register gives that trial other aids
    body = copy.deepcopy(remote_body(site, db, local[1]["id"]))
    body["aids"]["reference_planes"] = False
    status, answer, _ = call(site, "POST", "/api/attempts", body, tina)
    assert status == 422 and len(answer["error"].splitlines()) == 1, answer
    assert "but the upload says aids none" in answer["error"] and "must have its allocation" in answer["error"]
    # the same trial again, as it was: a trial counts once
    status, answer, _ = call(site, "POST", "/api/attempts", remote_body(site, db, local[1]["id"]), tina)
    assert status == 422 and "is already on this server" in answer["error"], answer


def remote_body(site, db, local_id: int) -> dict:
    """What the simulator sent for the local trial ``local_id`` (the outbox keeps it)."""
    import json

    from chainsim.game.records.store import RecordStore

    with RecordStore(db) as store:
        local = store.get_attempt(local_id)
        rows = store.query("SELECT attempt FROM outbox WHERE server = ? ORDER BY id", (site.url,))
    for row in rows:
        body = json.loads(row["attempt"])
        if body["details"]["protocol"]["order"] == local["details"]["protocol"]["order"]:
            return {**body, "class_name": "c1", "trainee": "P1"}
    raise AssertionError(f"no upload of trial {local_id}")


def test_a_trial_of_an_unfiled_study_is_refused(site):
    body = upload()
    body["details"]["protocol"] = {"study": f"s{uuid.uuid4().hex[:8]}", "participant": "alice", "order": 1}
    status, answer, _ = call(site, "POST", "/api/attempts", body, site.tokens["alice"])
    assert status == 422 and "has no design on this server" in answer["error"]


def test_with_the_server_out_of_reach_a_trial_is_kept_and_queued(tmp_path, monkeypatch):
    """Offline the session goes on: the trial is in the local records and waits in the outbox for the next
    sync, and the window says so."""
    from chainsim.components.hud import HudState
    from chainsim.components.input_events import PickPoint, Widget
    from chainsim.components.resources import PendingInput
    from chainsim.game.records import remote
    from chainsim.game.records.store import RecordStore
    from chainsim.game.study.protocol import load_protocol
    from chainsim.game.study.questionnaire import PRE
    from chainsim.game.study.session import StudySession
    from chainsim.game.trainer.headless import build_app
    from chainsim.game.trainer.inputscript import load_script

    monkeypatch.setenv("CHAINSIM_RECORDS_TOKEN", "anything")
    proto_file = tmp_path / "offline.toml"
    proto_file.write_text(PROTOCOL.replace("practice = 1", "practice = 0"))
    db = tmp_path / "local.sqlite3"
    app = build_app("prp", settings={"db": str(db), "class": "c1", "trainee": "P1"})
    allocation = {"by": "records server", "design": "balanced Latin square", "slot": 0, "group": "novice"}
    try:
        s = StudySession(
            app, load_protocol(proto_file), "P1", "c1", db, allocation=allocation, records="http://127.0.0.1:9"
        )
        s.start()
        for _ in PRE:
            s.key("return")
        s.key("return")  # the first trial's page
        now = app.time.sim_time
        picks = [e for _, e in load_script(SCRIPTS / "correct.toml") if isinstance(e, PickPoint)]
        events = [(now + 0.3 + 0.1 * k, p) for k, p in enumerate(picks)] + [(now + 1.0, Widget("save", None))]
        app.resource(PendingInput).extend(events)
        for _ in range(int(1.5 / app.time.dt)):
            app.update(app.time.dt)
            s.update()
        assert s.k == 1, app.resource(HudState).messages
        said = " ".join(m for m, _ in app.resource(HudState).messages)
    finally:
        app.close()
    with RecordStore(db) as store:
        assert len(store.list_attempts("c1", "P1")) == 1
        (queued,) = remote.pending(store)
    assert queued["server"] == "http://127.0.0.1:9" and "trial saved here" in said and "waits in the queue" in said

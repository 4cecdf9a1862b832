"""Each attempt has its own clock, path, contacts and step times; Save closes it (issue: saved
attempts added up). Two attempts in one session are saved and each is checked against its own events."""

from __future__ import annotations

import pytest

from chainsim.components.input_events import Widget
from chainsim.components.resources import PendingInput
from chainsim.game.packbuild.needle.make_prp_mouse_script import SCRIPTS
from chainsim.game.records.store import RecordStore
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script

DT = 1.0 / 120.0


def test_two_attempts_in_one_session_are_saved_each_with_its_own_figures(tmp_path):
    db = tmp_path / "records.sqlite3"
    app = build_app("prp", settings={"db": str(db), "class": "c1", "trainee": "alice"})
    try:
        pending = app.resource(PendingInput)
        correct = load_script(SCRIPTS / "correct.toml")
        last = max(t for t, _ in correct)
        # attempt 1: the correct attempt, saved at t = 8
        pending.extend([(t, e) for t, e in correct] + [(8.0, Widget("save"))])
        # attempt 2 begins with Reset at t = 20 (12 s after the save: that time belongs to neither);
        # the needle is tilted up a little and runs into the mandible, withdrawn, turned again and saved at t = 30
        t2 = 20.0
        pending.extend(
            [
                (t2, Widget("reset")),
                (t2 + 1.0, Widget("rotate_vertical", 10.0)),
                (t2 + 2.0, Widget("insert", 80.0)),
                (t2 + 4.0, Widget("insert", 0.0)),
                (t2 + 7.0, Widget("rotate_horizontal", 5.0)),
                (30.0, Widget("save")),
            ]
        )
        app.run_steps(int(31.0 / DT))
    finally:
        app.close()
    with RecordStore(db) as store:
        a1, a2 = store.list_attempts("c1", "alice")
    # attempt 1 stopped its clock when the needle entered the foramen, before the save
    assert a1["target"].startswith("foramen_ovale") and a1["duration_s"] <= last + 0.5
    assert a1["redirections"] == 0
    # attempt 2: from the Reset at t = 20 to the save at t = 30
    assert a2["duration_s"] == pytest.approx(10.0, abs=0.05)
    assert sum(a2["step_times"].values()) == pytest.approx(a2["duration_s"], abs=1e-6)
    assert a2["step_times"] != a1["step_times"]
    assert a2["skull_contacts"] >= 1 and a1["skull_contacts"] == 0
    assert a2["redirections"] == 1
    # path: in to the bone contact, back to the skin; nothing of attempt 1's insertion
    assert a2["path_length_mm"] < 2 * 80.0 + 1.0
    assert a2["path_length_mm"] != pytest.approx(a1["path_length_mm"])
    assert a1["path_length_mm"] < 2 * 120.0

"""What a records server accepts of a study trial (chainsim.game.study.protocol): the trial its design and
register give that place of the participant's session, and in the recording only the events a study
session sets itself, where it sets them."""

from __future__ import annotations

import pytest

from chainsim.game.study import protocol
from chainsim.systems.engine.errors import UserError

DESIGN = {
    "pack": "prp",
    "practice": 1,
    "trials": [
        {"name": "planes", "task": "location", "condition": "reference_planes", "repeat": 1,
         "aids": {"reference_planes": True}},
        {"name": "none", "task": "location", "condition": "without_clues", "repeat": 1, "aids": {}},
        {"name": "viewer", "task": "insertion", "condition": "local_viewer", "repeat": 1, "aids": {"tip_view": True}},
    ],
}  # fmt: skip
ENTRY = {"class_name": "c1", "slot": 1, "group": "novice", "year_of_training": 1, "procedures_performed": 0}
POINT = (10.0, 20.0, 30.0)


class Pack:
    """The one section of a pack the checks read: its points."""

    def section(self, name):
        assert name == "points"
        return {"landmark1_ideal_left": {"position": list(POINT)}}


def claim(order: int, **over) -> dict:
    design = protocol.clean_design(DESIGN, "s1")
    t = protocol.plan(design, ENTRY["slot"])[order - 1]
    said = {"study": "s1", "participant": "P1", "order": order, "trial": t["name"], "condition": t["condition"]}
    said.update(practice=t["practice"], allocation={"slot": ENTRY["slot"]}, aids=t["aids"])
    return {**said, **over}


def check(said: dict) -> dict:
    return protocol.check_claim(said, protocol.clean_design(DESIGN, "s1"), ENTRY, ("c1", "P1"))


def test_the_servers_trial_is_kept_and_one_not_allocated_refused_in_one_line():
    design = protocol.clean_design(DESIGN, "s1")
    trials = protocol.plan(design, ENTRY["slot"])
    # slot 1: the location conditions in the second row (without clues first), practice first
    assert [(t["name"], t["practice"]) for t in trials] == [
        ("none", True),
        ("none", False),
        ("planes", False),
        ("viewer", True),
        ("viewer", False),
    ]
    for order, t in enumerate(trials, 1):
        kept = check(claim(order))
        assert (kept["trial"], kept["practice"], kept["aids"]) == (t["name"], t["practice"], t["aids"])
        assert kept["allocation"]["by"] == "records server" and kept["group"] == "novice"
    for wrong, says in (
        (claim(3, aids={"reference_planes": False}), "says aids none"),
        (claim(2, condition="reference_planes"), "says condition 'reference_planes'"),
        (claim(1, practice=False), "says practice False"),
        (claim(2, allocation={"slot": 0}), "says slot 0"),
    ):
        with pytest.raises(UserError) as info:
            check(wrong)
        assert says in str(info.value) and "\n" not in str(info.value)
    with pytest.raises(UserError, match="not in the register"):
        protocol.check_claim(claim(1), design, ENTRY, ("c2", "P1"))
    with pytest.raises(UserError, match="has no design on this server"):
        protocol.check_claim(claim(1), None, ENTRY, ("c1", "P1"))


SAID = {"study": "s1", "participant": "P1", "order": 5, "trial": "viewer", "condition": "local_viewer"}
SAID.update(practice=False, slot=1)


def recording(*events: dict) -> dict:
    return {"protocol": dict(SAID), "event": list(events)}


def test_only_the_sessions_own_events_pass_where_it_sets_them():
    trial = {**{k: v for k, v in SAID.items() if k != "slot"}, "task": "insertion", "aids": {}}
    trial["allocation"] = {"slot": 1}
    aid = {"t": 0.01, "kind": "widget", "name": "tip_view", "value": True}
    reset = {"t": 0.05, "kind": "widget", "name": "reset", "value": "all"}
    pick = {"t": 0.08, "kind": "pick", "entity": "skin", "point": list(POINT), "button": "left"}
    protocol.check_session_events(recording(aid, reset, pick), trial, Pack())
    refused = [
        (recording(reset, {**aid, "t": 1.0}), trial, "sets widget 'tip_view'"),  # an aid turned on mid-trial
        (recording({**aid, "name": "save"}, reset), trial, "sets widget 'save'"),
        (recording(reset, {**pick, "point": [10.0, 20.0, 31.0]}), trial, "marks a point"),
        (recording(reset, pick), {**trial, "task": "location"}, "marks a point"),  # a location trial marks its own
        (recording(reset), {**trial, "order": 4}, "not of this trial: its protocol's order"),
        (recording(reset), {**trial, "allocation": {"slot": 0}}, "not of this trial: its protocol's slot"),
    ]
    for rec, t, says in refused:
        with pytest.raises(UserError, match=says):
            protocol.check_session_events(rec, t, Pack())


def test_the_aids_are_locked_from_each_trials_start_to_the_next_trials_page():
    events = [
        {"t": 1.01, "kind": "widget", "name": "tip_view"},
        {"t": 1.05, "kind": "widget", "name": "reset"},
        {"t": 9.01, "kind": "widget", "name": "tip_view"},
        {"t": 12.05, "kind": "widget", "name": "reset"},
        {"t": 13.0, "kind": "mouse_move"},
    ]
    locks = protocol.aid_locks(events)
    assert locks[0] == pytest.approx((1.2, 9.005)) and locks[1][0] == pytest.approx(12.2)
    assert locks[1][1] == float("inf")

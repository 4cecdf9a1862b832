"""The needle-procedure vocabulary read by the generic systems: what a pack declares changes what the
needle and the steps do, with no code of the pack's own (docs/needle-procedures.md).

Each test rewrites one part of the synthetic rhizotomy pack (tests/unit/test_needle.py) and checks
the behaviour a modder relies on: an obstacle that stops or only warns, a landmark score chosen by
name, the events steps are done on, and one clear line for an event that does not exist.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_needle import FORAMEN, L1, PLATE_Z, Run, make_synthetic_pack, on_skin

from chainsim.components.input_events import PickPoint, Widget
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures.needle.collision import NeedleHit


def _pack(tmp_path, old: str, new: str):
    root = make_synthetic_pack(tmp_path)
    text = (root / "pack.toml").read_text()
    assert old in text
    (root / "pack.toml").write_text(text.replace(old, new, 1))
    return root


SKULL = 'labels = ["the skull", "the mandible", "foramen ovale {side}"]\non_contact = "bounce"'


def _hit_the_plate(r: Run):
    r.send(PickPoint("skin", tuple(L1)))
    r.aim_at([0.0, 0.0, PLATE_Z[0]])  # the plate between the two holes
    r.send(Widget("insert", 200.0), steps=1)


def test_an_obstacle_that_stops_holds_the_needle_where_it_touched(tmp_path):
    r = Run(_pack(tmp_path, SKULL, SKULL.replace("bounce", "stop")))
    try:
        _hit_the_plate(r)
        contact = r.needle.depth
        r.send(steps=60)
        assert r.needle.depth == pytest.approx(contact) and r.needle.target_depth == pytest.approx(contact)
        assert r.needle.contacts == {"skull": 1} and not r.needle.done
        assert r.proc.lights["skull"] == "red"  # the pack's feedback for contact:skull
    finally:
        r.close()


def test_an_obstacle_that_warns_is_counted_once_and_passed(tmp_path):
    r = Run(_pack(tmp_path, SKULL, SKULL.replace("bounce", "warn")))
    try:
        _hit_the_plate(r)
        r.send(steps=5)
        hits = r.emitted(NeedleHit)
        assert [h.object for h in hits] == ["skull"] and hits[0].role == "skull"
        assert r.needle.depth == pytest.approx(150.0)  # through the plate to the needle's max_depth
        assert r.needle.contacts == {"skull": 1}
        assert r.needle.tip()[2] > PLATE_Z[1] + 10.0  # aimed up from below: now above the plate
    finally:
        r.close()


def test_the_landmark_score_is_chosen_by_name(tmp_path):
    r = Run(_pack(tmp_path, 'landmark_score = "thesis-6.1.5"', 'landmark_score = "mean-distance"'))
    try:
        for p in (L1, on_skin([30, 80, 30]), on_skin([80, 20, 0])):
            r.send(PickPoint("skin", tuple(p)))
        r.send(Widget("self_assessment"))
        from chainsim.components.resources import Assessment

        a = r.app.resource(Assessment).values
        assert a["landmark_error_mm"] == pytest.approx((a["D1"] + a["D2"] + a["D3"]) / 3.0)
        assert a["d1"] > 0.0 or a["d3"] > 0.0  # the planes are measured but not part of this score
    finally:
        r.close()


def test_a_step_is_done_on_the_event_the_pack_names(tmp_path):
    # orient_vertical is done by pressing a button instead of by inserting
    old = 'docs = "howto"\ndone_on = ["depth"]'
    r = Run(_pack(tmp_path, old, 'docs = "howto"\ndone_on = ["button:xray_take"]'))
    try:
        r.send(PickPoint("skin", tuple(L1)))
        r.aim_at(FORAMEN["left"])
        assert r.proc.step_id == "orient_vertical"
        r.send(Widget("insert", 10.0))
        assert r.proc.step_id == "orient_vertical"  # inserting no longer completes it
        r.send(Widget("xray_take"))
        assert r.proc.step_id == "insert"
    finally:
        r.close()


def test_an_unknown_event_is_one_clear_line(tmp_path):
    root = _pack(tmp_path, 'done_on = ["depth"]', 'done_on = ["depht"]')
    with pytest.raises(UserError, match="'depht' is not an event of the needle procedure"):
        Run(root)


def test_a_plane_through_three_named_points_scores_d(tmp_path):
    old = 'planes = ["sagittal_pupil_{side}", "pupil_sagittal_{side}", "saggital_pupil_{side}", "sagittal_{side}"]'
    new = 'plane_through = ["oral_commissure_{side}", "pupil_medial_{side}", "tragus_{side}"]'
    r = Run(_pack(tmp_path, old, new))
    try:
        l2 = on_skin([30, 80, 30])
        for p in (L1, l2, on_skin([80, 20, 0])):
            r.send(PickPoint("skin", tuple(p)))
        r.send(Widget("self_assessment"))
        from chainsim.components.resources import Assessment

        a = r.app.resource(Assessment).values
        # the synthetic pack's left points (tests/unit/test_needle.py)
        m, p, t = np.array([25.0, 80.0, -40.0]), np.array([30.0, 80.0, 30.0]), np.array([85.0, -10.0, 0.0])
        n = np.cross(p - m, t - m)
        placed = np.asarray(a["landmarks"][1])  # the click, snapped onto the skin mesh
        assert a["d2"] == pytest.approx(abs((placed - m) @ n) / np.linalg.norm(n))
    finally:
        r.close()


def test_a_misspelt_entity_in_a_role_is_one_clear_line(tmp_path):
    """A role that names an entity the pack does not have is refused, not silently narrowed."""
    old = 'entities = ["skull", "mandible", "foramen_ovale_{side}"]'
    root = _pack(tmp_path, old, old.replace('"mandible"', '"mandibel"'))
    with pytest.raises(UserError, match=r"roles\.skull\.entities: 'mandibel' is not an entity of the pack"):
        Run(root)

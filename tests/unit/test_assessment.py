"""Assessment of a needle-procedure attempt on the rhizotomy pack (thesis 6.1.5 error formulas, the 3.3.4 tool)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_needle import L1, Run, make_synthetic_pack, on_skin

from chainsim.components.input_events import PickPoint, Widget
from chainsim.systems.procedures.needle.manifest import LandmarkTarget, Plane, landmark_errors

coord = st.floats(-100.0, 100.0, allow_nan=False)
point = st.tuples(coord, coord, coord)


def _anat(mouth, pupil, tragus, normals):
    """The three landmarks of 3.3.4 as the rhizotomy pack declares them: 25 mm from the mouth corner,
    on the pupil, 30 mm from the tragus, each with a plane through its point."""
    out = []
    for p, ideal, n in zip((mouth, pupil, tragus), (25.0, 0.0, 30.0), normals):
        n = np.asarray(n, float)
        out.append(LandmarkTarget(np.array(p, float), ideal, Plane(np.array(p, float), n / np.linalg.norm(n))))
    return out


@settings(max_examples=50, deadline=None)
@given(
    point,
    point,
    point,
    point,
    point,
    point,
    st.tuples(point, point, point).filter(lambda ns: all(np.linalg.norm(n) > 1e-3 for n in ns)),
)
def test_landmark_error_is_the_6_1_5_formula(m, p, t, a, b, c, normals):
    anat = _anat(m, p, t, normals)
    lms = np.array([a, b, c], float)
    got = landmark_errors(anat, lms)

    def plane_dist(x, origin, n):
        n = np.asarray(n, float) / np.linalg.norm(n)
        return abs(float(np.dot(np.subtract(x, origin), n)))

    D1 = abs(np.linalg.norm(np.subtract(a, m)) - 25.0)
    D2 = np.linalg.norm(np.subtract(b, p))
    D3 = abs(np.linalg.norm(np.subtract(c, t)) - 30.0)
    d1, d2, d3 = plane_dist(a, m, normals[0]), plane_dist(b, p, normals[1]), plane_dist(c, t, normals[2])
    assert got["D1"] == pytest.approx(D1) and got["D2"] == pytest.approx(D2) and got["D3"] == pytest.approx(D3)
    assert got["d1"] == pytest.approx(d1) and got["d2"] == pytest.approx(d2) and got["d3"] == pytest.approx(d3)
    assert got["landmark_error_mm"] == pytest.approx(((D1 + d1) + (D2 + d2) + (D3 + d3)) / 6.0)


def test_landmark_error_is_none_until_all_three_are_placed():
    anat = _anat((0, 0, 0), (0, 1, 0), (1, 0, 0), ((0, 0, 1), (1, 0, 0), (0, 0, 1)))
    lms = np.full((3, 3), np.nan)
    lms[0] = [25, 0, 0]
    got = landmark_errors(anat, lms)
    assert got["landmark_error_mm"] is None and got["D1"] == pytest.approx(0.0) and got["D2"] is None


@pytest.fixture(scope="module")
def pack_dir(tmp_path_factory):
    return make_synthetic_pack(tmp_path_factory.mktemp("prp_assess"))


PICKS = [L1, on_skin([30, 80, 30]), on_skin([80, 20, 0])]


def _full_attempt(r: Run):
    for p in PICKS:
        r.send(PickPoint("skin", tuple(p)))
    r.aim_at([25.0, 0.0, -2.0])
    r.send(Widget("insert", 250.0), steps=5)


def test_self_assessment_fills_the_panel_and_summary_values(pack_dir):
    from chainsim.components.hud import HudState
    from chainsim.components.resources import Assessment

    r = Run(pack_dir)
    try:
        _full_attempt(r)
        r.send(Widget("self_assessment"))
        a = r.app.resource(Assessment).values
        text = "\n".join(r.app.resource(HudState).panel_text)
        assert f"{a['landmark_error_mm']:.1f} mm" in text
        assert f"{a['needle_error_mm']:.1f} mm" in text
        assert a["target"] == "foramen_ovale_left" and a["skull_contacts"] == 0
        for key in (
            "D1",
            "D2",
            "D3",
            "d1",
            "d2",
            "d3",
            "landmarks",
            "rotation_refused",
            "step_times",
            "aids",
            "path_length_mm",
        ):
            assert key in a
        assert a["path_length_mm"] == pytest.approx(r.needle.depth)
        assert sum(a["step_times"].values()) == pytest.approx(a["duration_s"])
        assert a["aids"]["tip_view"] is True and a["aids"]["reference_planes"] is False
    finally:
        r.close()


def test_save_stores_the_attempt_under_class_and_trainee(pack_dir, tmp_path):
    from chainsim.game.records.store import RecordStore

    db = tmp_path / "rec.sqlite3"
    r = Run(pack_dir, settings={"db": str(db), "class": "c1", "trainee": "alice"})
    try:
        _full_attempt(r)
        r.send(Widget("save"))
        a = r.app.resource(__import__("chainsim.game.trainer.headless", fromlist=["Assessment"]).Assessment).values
    finally:
        r.close()
    with RecordStore(db) as store:
        rows = store.list_attempts("c1", "alice")
    assert len(rows) == 1
    row = rows[0]
    assert row["target"] == "foramen_ovale_left"
    assert row["landmark_error_mm"] == pytest.approx(a["landmark_error_mm"])
    assert row["needle_error_mm"] == pytest.approx(a["needle_error_mm"])
    assert row["details"]["D1"] == pytest.approx(a["D1"])


def test_a_failing_save_shows_the_error_and_the_session_goes_on(pack_dir, tmp_path):
    from chainsim.components.hud import HudState

    bad = tmp_path / "not-a-db"
    r = Run(pack_dir, settings={"db": str(bad)})
    try:
        _full_attempt(r)
        bad.write_text("hello, this is not sqlite")  # the file went bad during the session
        r.send(Widget("save"))
        msgs = [m for m, _ in r.app.resource(HudState).messages]
        assert any(m.startswith("Not saved:") and "not an SQLite database" in m for m in msgs)
        r.send(Widget("reset"))  # still running
        assert r.needle.depth == 0.0
    finally:
        r.close()
    assert bad.read_text() == "hello, this is not sqlite"


def test_saving_before_the_landmarks_is_refused_with_a_message(pack_dir, tmp_path):
    from chainsim.components.hud import HudState

    r = Run(pack_dir, settings={"db": str(tmp_path / "x.sqlite3")})
    try:
        r.send(Widget("save"))
        assert any("landmarks" in m for m, _ in r.app.resource(HudState).messages)
    finally:
        r.close()
    assert not (tmp_path / "x.sqlite3").exists()

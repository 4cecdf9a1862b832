"""The long runs (tools/study/long_runs.py): the scenarios are the ones the study promises, the shape figures
read what a hand-made tetrahedron or trajectory implies, and both command lines run them and refuse bad
parts in one line. These check the measuring, not how well any model does."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from chainsim.game.cli.main import main
from chainsim.systems.engine.errors import UserError
from chainsim.tools.bench import models
from chainsim.tools.study import long_runs as lr
from chainsim.tools.study import surgical

UNIT_TET = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
ONE = np.array([[0, 1, 2, 3]])


def test_the_scenarios_are_the_holds_drags_and_pulls_the_study_promises():
    sc = {s.name: s for s in lr.SCENARIOS}
    assert (sc["hold"].offset, sc["hold"].ramp, sc["hold"].frames) == ((0.0, 0.0, 3.0), 1, 600)
    assert (sc["drag"].pull, sc["drag"].ramp, sc["drag"].frames) == (4.0, 90, 90)
    assert (sc["drag-hold"].ramp, sc["drag-hold"].frames) == (90, 390)
    assert sc["corner-drag-hold"].region == "corner"
    assert (sc["shear"].offset, sc["shear"].frames) == ((12.0, 0.0, 0.0), 120)
    assert (sc["lift"].offset, sc["lift"].frames) == ((0.0, 0.0, 10.0), 120)
    # a drag's target moves every frame and arrives on its last ramp frame; an at-once pull arrives on frame 1
    fr = [sc["drag"].fraction(f) for f in range(1, 91)]
    assert np.all(np.diff(fr) > 0) and fr[-1] == 1.0 and sc["shear"].fraction(1) == 1.0
    # flicker counts from the hold's second second on
    assert not sc["hold"].counts_flicker(60) and sc["hold"].counts_flicker(61)
    assert not any(sc["drag"].counts_flicker(f) for f in range(1, 91))


def test_the_corner_region_is_a_top_corner_square():
    b = surgical.block(lr.QUICK_MM)
    c = lr.region(b, "corner")
    assert len(c) == 9 and np.all(b.pos[c, 2] == surgical.BLOCK_MM[2])
    assert np.all(b.pos[c, :2] <= lr.CORNER_MM) and np.array_equal(lr.region(b, "patch"), b.grabbed)


def test_min_J_of_hand_made_tetrahedra():
    F = np.array([[2.0, 1.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 0.5]])  # upper triangular: det = 2 * 3 * 0.5
    x = UNIT_TET @ F.T + [5.0, -2.0, 1.0]
    assert lr.jacobians(UNIT_TET, ONE, x)[0] == pytest.approx(3.0)
    flat = UNIT_TET.copy()
    flat[3] = [0.0, 0.0, -0.5]  # the fourth corner pushed through the opposite face: edges e1, e2, -0.5 e3
    assert lr.jacobians(UNIT_TET, ONE, flat)[0] == pytest.approx(-0.5)
    # a rotated, scaled rest shape: a rigid turn of it reads 1, whatever its own volume
    c, s = np.cos(0.7), np.sin(0.7)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    rest = 2.0 * UNIT_TET @ R
    assert lr.jacobians(rest, ONE, rest @ R.T)[0] == pytest.approx(1.0)
    # on the study's block it agrees with the study's own volume ratio
    b = surgical.block(5.0)
    u = np.random.default_rng(1).normal(scale=0.8, size=b.pos.shape)
    assert lr.jacobians(b.pos, b.tets, b.pos + u).min() == pytest.approx(surgical.volume_figures(b, u)["min_J"])


def test_the_tracker_keeps_the_smallest_J_over_the_run():
    t = lr.Tracker(UNIT_TET, ONE, pull=1.0)
    flat = UNIT_TET.copy()
    flat[3] = [0.0, 0.0, -0.5]
    for x in (UNIT_TET, flat, UNIT_TET):
        t.frame(x, held=False)
    assert t.figures()["min_J"] == pytest.approx(-0.5)


def test_flicker_reads_a_two_shape_alternation_and_zero_for_a_still_body():
    rest = surgical.block(5.0).pos
    tets = surgical.block(5.0).tets
    a = rest + [0.0, 0.0, 1.0]
    b = a.copy()
    b[17] += [0.0, 0.64, 0.0]  # one node 0.64 mm back and forth, every frame
    still, alt = lr.Tracker(rest, tets, 3.0), lr.Tracker(rest, tets, 3.0)
    for f in range(1, 41):
        still.frame(a, held=f > 5)
        alt.frame(b if f % 2 else a, held=f > 5)
    assert still.figures()["flicker"] == 0.0 and still.figures()["flicker_two_frames"] == 0.0
    assert alt.figures()["flicker"] == pytest.approx(0.64 / 3.0)
    assert alt.figures()["flicker_two_frames"] == 0.0  # an alternation, not a drift
    # changes before the frames that count are not flicker; none counted reads None
    early = lr.Tracker(rest, tets, 3.0)
    for f in range(1, 11):
        early.frame(a + (0.1 * f if f <= 5 else 0.5), held=f > 5)
    assert early.figures()["flicker"] == 0.0
    never = lr.Tracker(rest, tets, 3.0)
    never.frame(b, held=False)
    assert never.figures()["flicker"] is None


def test_overshoot_reads_what_a_trajectory_implies():
    def shape(d):  # the held corner at the 3 mm target, the next one swung out by d along x
        return UNIT_TET + np.array([[0.0, 0.0, 3.0], [d, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])

    t = lr.Tracker(UNIT_TET, ONE, pull=3.0)
    for d in (1.0, 4.5, 3.5, 2.0):  # out to 4.5 mm and back: 4.5 / 3 - 1
        t.frame(shape(d), held=True)
    assert t.figures()["overshoot"] == pytest.approx(0.5)
    calm = lr.Tracker(UNIT_TET, ONE, pull=3.0)
    calm.frame(shape(1.0), held=True)
    assert calm.figures()["overshoot"] == pytest.approx(0.0)


def test_every_scenario_runs_on_the_quick_mesh_and_is_written(tmp_path):
    res = lr.run(lr.QUICK_MM, time_scale=0.05, only=["hybrid (defaults)"], cache=tmp_path / "fem")
    assert res["nodes"] == 1521 and [s["name"] for s in res["scenarios"]] == [s.name for s in lr.SCENARIOS]
    assert {r["setting"] for r in res["rows"]} == {"hybrid (defaults)", f"hybrid (defaults), sleeping {lr.SLEEP:g}"}
    for r in res["rows"]:
        assert r["status"] == "ran", r
        assert np.isfinite(r["error_end"]) and np.isfinite(r["min_J"]) and np.isfinite(r["overshoot"])
        assert r["cpu_ms"] > 0 and r["wall_ms"] > 0
        assert (r["flicker"] is None) == (r["scenario"] == "drag"), r  # a drag is never held
    for name, fem in res["fem"].items():
        assert fem["min_J"] > 0, name  # the converged reference inverts nothing
    md = lr.write(res, tmp_path, "test", "test machine")
    assert "## shear" in md.read_text() and json.loads((tmp_path / "long-runs.json").read_text())["rows"]
    # the references were kept: the next run reads them
    b = surgical.block(lr.QUICK_MM)
    u, info = lr.reference(b, b.grabbed, (0.0, 0.0, 3.0), 3e4, 0.45, tmp_path / "fem")
    assert info["status"] == "read from the cache" and u.shape == b.pos.shape


def test_a_run_too_slow_for_its_bound_stops_and_says_so():
    b = surgical.block(5.0)
    sc = lr.scenarios(names=["hold"])[0]
    u, info = lr.run_one(b, sc, "hybrid", {}, 3e4, 0.45, max_seconds=1e-9)
    assert u is None and info["status"].startswith("stopped after 3 frames") and info["frames_run"] == 3


def test_bench_models_runs_the_long_part_on_the_coarse_tissue_block(tmp_path, monkeypatch):
    monkeypatch.setattr(lr, "CACHE", tmp_path / "fem")
    args = SimpleNamespace(
        scene="tissue", element_mm=5.0, E=3e4, nu=0.45, n=6, frames=10, only="projective statics", out=str(tmp_path)
    )
    args.parts = "long"
    assert models.run(args) == 0
    info = json.loads((tmp_path / "long-runs.json").read_text())
    assert info["nodes"] == 245 and {r["setting"] for r in info["rows"]} == {"projective statics, CG 6, 1 it"}
    assert len(info["rows"]) == len(lr.SCENARIOS) and not (tmp_path / "results.json").exists()
    assert info["fem_cache"] == str(tmp_path / "fem") and list((tmp_path / "fem").glob("*.npz"))


@pytest.mark.parametrize(
    "kw, word",
    [
        ({"parts": "long,sideways"}, "--parts"),
        ({"parts": "long", "scene": "block"}, "--scene tissue"),
        ({"parts": "long", "only": "chainmail"}, "--only"),
    ],
)
def test_bench_models_refuses_bad_long_arguments(tmp_path, kw, word):
    base = {"scene": "tissue", "n": 6, "frames": 10, "only": None, "out": str(tmp_path), "E": 3e4, "nu": 0.45}
    with pytest.raises(UserError, match=word):
        models.run(SimpleNamespace(**{**base, "element_mm": 5.0, **kw}))


def test_study_surgical_refuses_an_unknown_part_in_one_line(tmp_path, capsys):
    assert main(["study", "surgical", "--parts", "table,longer", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert "--parts" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_a_blown_up_figure_stays_one_short_cell():
    assert lr._f(-4.84e33, "{:.2f}") == "-4.84e+33" and lr._f(-0.284, "{:.2f}") == "-0.28" and lr._f(None) == "-"


def test_frames_to_a_level_count_from_the_last_arrival():
    # 10 %: reached on frame 3, left on frame 4, back on frame 5 for good; 1 %: on the last frame only
    err = [0.5, 0.2, 0.08, 0.12, 0.04, 0.02, 0.009]
    assert lr.frames_to(err, (0.10, 0.05, 0.01)) == [5, 5, 7]
    assert lr.frames_to([0.5, 0.3], (0.10,)) == [None]  # never within
    assert lr.frames_to([0.0, 0.0], (0.01,)) == [1]  # within from the first frame
    assert lr.frames_to([0.05, float("nan")], (0.10,)) == [None]  # a blown-up end is not within
    assert lr.frames_to([], (0.10,)) == [None]


def test_the_stiffness_part_runs_on_the_quick_mesh_through_the_study_command(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(lr, "CACHE", tmp_path / "fem")
    monkeypatch.setattr(lr, "STIFF_MATERIALS", [(3e4, 0.45)])
    monkeypatch.setattr(lr, "STIFF_FRAMES", 6)
    assert main(["study", "surgical", "--quick", "--parts", "stiffness", "--out", str(tmp_path / "o")]) == 0
    res = json.loads((tmp_path / "o" / "stiffness.json").read_text())
    assert res["nodes"] == 1521 and res["frames"] == 6
    assert [r["setting"] for r in res["rows"]] == [s[1] for s in lr.STIFF_SETTINGS]
    for r in res["rows"]:
        assert r["status"] == "ran", r
        assert len(r["own_frames"]) == len(r["fem_frames"]) == 3 and r["cpu_ms"] > 0 and r["cpu_ms_mean"] > 0
        assert 0 <= r["own_end"] < 1 and 0 < r["fem_end"] < 1 and 0 < r["own_fem_error"] < 1
        # the counts are the levels' order: a tighter level is never reached sooner
        reached = [n for n in r["own_frames"] if n is not None]
        assert reached == sorted(reached)
    assert "| hybrid (defaults) | 30 | 0.45 |" in (tmp_path / "o" / "stiffness.md").read_text()
    assert "# Stiffness" in capsys.readouterr().out


def test_bench_models_runs_the_stiffness_part(tmp_path, monkeypatch):
    monkeypatch.setattr(lr, "CACHE", tmp_path / "fem")
    monkeypatch.setattr(lr, "STIFF_MATERIALS", [(3e4, 0.49)])
    monkeypatch.setattr(lr, "STIFF_FRAMES", 4)
    args = SimpleNamespace(
        scene="tissue", element_mm=5.0, E=3e4, nu=0.45, n=6, frames=10, only="hybrid", out=str(tmp_path)
    )
    args.parts = "stiffness"
    assert models.run(args) == 0
    info = json.loads((tmp_path / "stiffness.json").read_text())
    assert info["nodes"] == 245 and [(r["setting"], r["nu"]) for r in info["rows"]] == [("hybrid (defaults)", 0.49)]
    assert info["rows"][0]["status"] == "ran" and not (tmp_path / "long-runs.json").exists()
    with pytest.raises(UserError, match="no setting starts with"):
        models.run(SimpleNamespace(**{**vars(args), "only": "xpbd"}))

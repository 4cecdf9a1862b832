"""The exact-limit pass (after a cascade, every link inside its box) against the plain whole-mesh
reference on random meshes, materials, anchors, cut links and pulls, plus what a user relies on: no link
left outside, pins kept, targets reached when reachable and otherwise approached as near as the limits
allow, elements no violation reaches left alone. The exact step (exact_move, no cascade) against the same
reference: every link inside, the same shortfall, and every element at least as near where it started."""

from __future__ import annotations

import numpy as np
import pytest
from cascade_reference import MESH_KINDS, random_mesh
from exact_reference import link_terms, reach, ref_exact
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.kernels.chainmail import (
    ORDER_BALANCED,
    ORDER_BREADTH_FIRST,
    ORDER_DEPTH_FIRST,
    ORDER_SCHILL,
    cascade,
    make_workspace,
    material_arrays,
)
from chainsim.systems.engine.kernels.exact import exact_limits, exact_move, violations
from chainsim.systems.engine.kernels.graph import build_graph

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
ORDERS = (ORDER_BREADTH_FIRST, ORDER_BALANCED, ORDER_SCHILL, ORDER_DEPTH_FIRST)


@st.composite
def scenarios(draw):
    kind = draw(st.sampled_from(MESH_KINDS))
    dim = {"planar": 2, "surface": 3, "volume": 3}.get(kind) or draw(st.integers(1, 3))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    rest, links = random_mesh(kind, dim, rng, size=draw(st.integers(3, 7)))
    n, m = len(rest), len(links)
    if draw(st.booleans()):  # inhomogeneous tissue
        mats = (rng.uniform(0.0, 1.0, m), rng.uniform(1.0, 3.0, m), rng.uniform(0.0, 0.6, m))
    else:
        mats = draw(st.sampled_from([(1.0, 1.0, 0.0), (0.8, 1.2, 0.1), (0.5, 2.5, 0.3), (0.0, 4.0, 1.0)]))
    fixed = rng.random(n) < draw(st.sampled_from([0.0, 0.05, 0.2])) if draw(st.booleans()) else None
    alive = rng.random(m) > 0.1 if draw(st.booleans()) else np.ones(m, bool)
    k = draw(st.integers(1, 3))
    grabbed = rng.choice(n, size=min(k, n), replace=False).astype(np.int64)
    scale = draw(st.sampled_from([0.3, 1.0, 4.0, 12.0]))
    targets = rest[grabbed] + rng.normal(scale=scale, size=(len(grabbed), dim))
    order = draw(st.sampled_from(ORDERS))
    warm = draw(st.booleans())  # start from an earlier exact step instead of the rest shape
    return rest, links, alive, mats, fixed, grabbed, targets, order, warm, rng


def step(rest, pos, graph, mats, grabbed, targets, fixed, order, ws):
    """Cascade then the exact pass, in place; returns (moved, ExactResult)."""
    moved, _ = cascade(rest, pos, graph, *mats, grabbed, targets, fixed=fixed, order=order, workspace=ws)
    return moved, exact_limits(rest, pos, graph, *mats, moved, grabbed, targets, fixed, ws)


def setup(case):
    rest, links, alive, mats, fixed, grabbed, targets, order, warm, rng = case
    graph = build_graph(len(rest), links)
    graph.cut(~np.asarray(alive, bool))
    mats = material_arrays(len(links), *mats)
    ws = make_workspace(len(rest))
    pos = rest.copy()
    if warm:
        g0 = rng.choice(len(rest), size=1).astype(np.int64)
        step(rest, pos, graph, mats, g0, rest[g0] + rng.normal(scale=2.0, size=(1, rest.shape[1])), fixed, order, ws)
    return graph, mats, ws, pos


@SETTINGS
@given(scenarios())
def test_pass_matches_the_whole_mesh_reference(case):
    rest, links, alive, _, fixed, grabbed, targets, order, _, _ = case
    graph, mats, ws, pos = setup(case)
    moved, _ = cascade(rest, pos, graph, *mats, grabbed, targets, fixed=fixed, order=order, workspace=ws)
    after_cascade = pos.copy()
    res = exact_limits(rest, pos, graph, *mats, moved, grabbed, targets, fixed, ws)
    ref, ref_short = ref_exact(rest, after_cascade, links, graph.alive, *mats, grabbed, targets, fixed)
    scale = 1.0 + np.abs(ref).max()
    np.testing.assert_allclose(pos, ref, rtol=0, atol=1e-7 * scale)
    assert res.shortfall == pytest.approx(ref_short, abs=1e-7 * scale)
    assert res.complete


@SETTINGS
@given(scenarios())
def test_every_link_ends_inside_and_pins_stay(case):
    rest, links, alive, _, fixed, grabbed, targets, order, _, _ = case
    graph, mats, ws, pos = setup(case)
    start = pos.copy()
    moved, res = step(rest, pos, graph, mats, grabbed, targets, fixed, order, ws)
    assert np.all(np.isfinite(pos))
    v = violations(rest, pos, graph, *mats)
    assert v.outside == 0 and v.worst <= 1e-6, v
    assert res.residual <= 1e-6 and res.outside == 0
    if fixed is not None:
        np.testing.assert_array_equal(pos[fixed], start[fixed])
    free = grabbed if fixed is None else grabbed[~fixed[grabbed]]
    # only elements the cascade moved or the pass reports changed differ from the start
    touched = np.zeros(len(rest), bool)
    touched[moved] = True
    touched[res.changed] = True
    np.testing.assert_array_equal(pos[~touched], start[~touched])
    # a grabbed element ends at its target or reports how far short it stopped
    got = np.linalg.norm(pos[free] - targets[np.isin(grabbed, free)], axis=1)
    assert res.shortfall == pytest.approx(got.max() if len(got) else 0.0, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(MESH_KINDS), st.sampled_from(ORDERS))
def test_targets_are_reached_when_nothing_is_fixed(seed, kind, order):
    rng = np.random.default_rng(seed)
    dim = {"planar": 2, "surface": 3, "volume": 3}.get(kind, 3)
    rest, links = random_mesh(kind, dim, rng)
    graph = build_graph(len(rest), links)
    mats = material_arrays(len(links), 0.8, 1.2, 0.1)
    g = np.array([int(rng.integers(len(rest)))])
    t = rest[g] + rng.normal(scale=10.0, size=(1, dim))
    pos = rest.copy()
    _, res = step(rest, pos, graph, mats, g, t, None, order, make_workspace(len(rest)))
    assert res.shortfall == 0.0
    np.testing.assert_array_equal(pos[g], t)
    assert violations(rest, pos, graph, *mats).outside == 0


def test_unreachable_target_stops_at_the_nearest_reachable_point():
    """A chain anchored at one end, stretched past what its links allow: the free end stops where every
    link is at its longest, and the result says by how much it fell short."""
    rest, links = meshgen.chain(6, 1.0, dim=1)
    graph = build_graph(6, links)
    mats = material_arrays(5, 0.8, 1.2, 0.0)
    fixed = np.zeros(6, bool)
    fixed[0] = True
    pos = rest.copy()
    _, res = step(rest, pos, graph, mats, np.array([5]), np.array([[10.0]]), fixed, ORDER_BREADTH_FIRST, None)
    np.testing.assert_allclose(pos[:, 0], 1.2 * np.arange(6), atol=1e-12)
    assert res.shortfall == pytest.approx(10.0 - 6.0, abs=1e-12)
    # the plain cascade leaves the last link stretched to five rest lengths instead
    plain = rest.copy()
    cascade(rest, plain, graph, *mats, np.array([5]), np.array([[10.0]]), fixed=fixed)
    assert violations(rest, plain, graph, *mats).worst > 1.0


def test_reachable_box_of_the_reference_matches_a_hand_count():
    """The reference itself: an element two links from an anchor may go 2 * 0.2 further (stretch) and
    2 * 0.2 nearer (compression) than at rest."""
    rest, links = meshgen.chain(3, 1.0, dim=1)
    i, j, c, w, _ = link_terms(rest, links, np.ones(2, bool), *material_arrays(2, 0.8, 1.2, 0.0))
    lo, hi = reach(rest[:, 0], i, j, c[:, 0], w[:, 0], np.array([0]), 2)
    assert (lo, hi) == pytest.approx((1.6, 2.4))


def test_float32_positions_end_inside_to_their_rounding():
    rest, _, links = meshgen.triangulated_grid(12, 12, dim=3)
    rest = rest.astype(np.float32)
    graph = build_graph(len(rest), links)
    mats = material_arrays(len(links), 0.8, 1.2, 0.1)
    pos = rest.copy()
    t = (rest[70] + np.array([4.0, -3.0, 5.0], np.float32))[None]
    _, res = step(rest, pos, graph, mats, np.array([70]), t, None, ORDER_BREADTH_FIRST, make_workspace(len(rest)))
    assert pos.dtype == np.float32
    assert res.residual <= 1e-5 and violations(rest, pos, graph, *mats).outside == 0


def test_visit_cap_stops_and_says_so():
    rest, _, links = meshgen.triangulated_grid(15, 15, dim=3)
    graph = build_graph(len(rest), links)
    mats = material_arrays(len(links), 0.8, 1.2, 0.1)
    pos = rest.copy()
    t = rest[112][None] + 6.0
    moved, _ = cascade(rest, pos, graph, *mats, np.array([112]), t)
    res = exact_limits(rest, pos, graph, *mats, moved, np.array([112]), t, max_visits=5)
    assert not res.complete and res.visits <= 5 + 1
    assert np.all(np.isfinite(pos))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(grabbed=np.array([99])), "grabbed ids"),
        (dict(moved=np.array([-1])), "moved ids"),
        (dict(targets=np.array([[np.nan, 0.0]])), "finite"),
    ],
)
def test_bad_arguments_raise_before_anything_moves(kwargs, match):
    rest, links = meshgen.grid((4, 4))
    graph = build_graph(16, links)
    mats = material_arrays(len(links), 0.8, 1.2, 0.1)
    pos = rest + 0.5
    before = pos.copy()
    args = dict(moved=np.array([0]), grabbed=np.array([0]), targets=np.array([[0.5, 0.5]])) | kwargs
    with pytest.raises(ValueError, match=match):
        exact_limits(rest, pos, graph, *mats, args["moved"], args["grabbed"], args["targets"])
    np.testing.assert_array_equal(pos, before)


@SETTINGS
@given(scenarios(), st.lists(st.sampled_from(["same", "toggle", "cut", "relaxed"]), min_size=2, max_size=5))
def test_repeated_pulls_match_the_reference_whatever_changes_between_them(case, steps):
    """A drag repeats the same pull: the pass then reads the reachable boxes from a field it builds once;
    anchors toggled in place, links cut or positions changed after the cascade in between must all be
    noticed. Each step matches the whole-mesh reference, keeps
    every link inside and the fixed elements where they were."""
    rest, links, alive, _, fixed, grabbed, targets, order, _, rng = case
    graph, mats, ws, _ = setup(case)
    fixed = np.zeros(len(rest), bool) if fixed is None else fixed.copy()
    for what in ["same"] + steps:
        if what == "toggle":
            fixed[rng.integers(len(rest))] ^= True
        elif what == "cut" and len(links):
            graph.cut(rng.choice(len(links), size=1))
        pos = rest.copy()
        moved, _ = cascade(rest, pos, graph, *mats, grabbed, targets, fixed=fixed, order=order, workspace=ws)
        if what == "relaxed":  # positions changed after the cascade (as relaxation does)
            pos[moved] += rng.normal(scale=0.05, size=pos[moved].shape) * (~fixed[moved])[:, None]
            pos[grabbed] = np.where(fixed[grabbed, None], pos[grabbed], targets)
        after = pos.copy()
        res = exact_limits(rest, pos, graph, *mats, moved, grabbed, targets, fixed, ws)
        ref, ref_short = ref_exact(rest, after, links, graph.alive, *mats, grabbed, targets, fixed)
        scale = 1.0 + np.abs(ref).max()
        np.testing.assert_allclose(pos, ref, rtol=0, atol=1e-7 * scale)
        assert res.shortfall == pytest.approx(ref_short, abs=1e-7 * scale)
        assert violations(rest, pos, graph, *mats).outside == 0
        np.testing.assert_array_equal(pos[fixed], rest[fixed])


@SETTINGS
@given(scenarios(), st.booleans())
def test_exact_step_is_inside_and_at_least_as_near_as_the_reference(case, check):
    """The step from a shape whose links hold (rest, or an earlier exact step): no link outside, fixed
    elements kept, the same stop as the reference when a target is out of reach, and on every axis each
    element moved no further from where it started than the reference (cascade, then its closures) moved
    it: the closures of the start shape are the nearest shape with the pins in place (exact.py)."""
    rest, links, alive, _, fixed, grabbed, targets, order, warm, rng = case
    graph = build_graph(len(rest), links)
    graph.cut(~np.asarray(alive, bool))
    mats = material_arrays(len(links), *case[3])
    ws = make_workspace(len(rest))
    pos = rest.copy()
    if warm:
        g0 = rng.choice(len(rest), size=1).astype(np.int64)
        exact_move(rest, pos, graph, *mats, g0, rest[g0] + rng.normal(scale=2.0, size=(1, rest.shape[1])), fixed, ws)
        assert violations(rest, pos, graph, *mats).outside == 0
    start = pos.copy()
    changed, res = exact_move(rest, pos, graph, *mats, grabbed, targets, fixed, ws, order=order, check=check)
    changed = changed.copy()
    v = violations(rest, pos, graph, *mats)
    assert v.outside == 0 and v.worst <= 1e-6, v
    assert res.complete and res.outside == 0
    if fixed is not None:
        np.testing.assert_array_equal(pos[fixed], start[fixed])
    untouched = np.ones(len(rest), bool)
    untouched[changed] = False
    np.testing.assert_array_equal(pos[untouched], start[untouched])
    ref_start = start.copy()
    moved, _ = cascade(rest, ref_start, graph, *mats, grabbed, targets, fixed=fixed, order=order, workspace=ws)
    ref, ref_short = ref_exact(rest, ref_start, links, graph.alive, *mats, grabbed, targets, fixed)
    scale = 1.0 + np.abs(ref).max()
    assert res.shortfall == pytest.approx(ref_short, abs=1e-7 * scale)
    assert np.all(np.abs(pos - start) <= np.abs(ref - start) + 1e-7 * scale)


def test_exact_step_on_a_pulled_block_moves_only_what_it_must():
    """A 6^3 block, base fixed, a top corner pulled up 1 (in reach) and then 40 (out of reach): the step
    reaches the target or stops where the reference stops, and elements far from the pull stay."""
    rest, _, links = meshgen.tet_grid(6, 6, 6)
    rest = np.ascontiguousarray(rest, dtype=np.float64)
    graph = build_graph(len(rest), links)
    mats = material_arrays(len(links), 0.8, 1.2, 0.1)
    fixed = rest[:, 2] <= rest[:, 2].min() + 1e-9
    g = np.array([int(np.argmax(rest.sum(axis=1)))])
    for lift in (1.0, 40.0):
        pos = rest.copy()
        target = rest[g] + np.array([[0.0, 0.0, lift]])
        changed, res = exact_move(rest, pos, graph, *mats, g, target, fixed, make_workspace(len(rest)))
        ref_pos = rest.copy()
        moved, _ = cascade(rest, ref_pos, graph, *mats, g, target, fixed=fixed)
        ref, short = ref_exact(rest, ref_pos, links, graph.alive, *mats, g, target, fixed)
        assert violations(rest, pos, graph, *mats).outside == 0
        assert res.shortfall == pytest.approx(short, abs=1e-9)
        assert np.all(np.abs(pos - rest) <= np.abs(ref - rest) + 1e-9)
        if lift == 1.0:
            assert res.shortfall == 0.0 and len(changed) < len(rest) // 2


@SETTINGS
@given(scenarios(), st.lists(st.sampled_from(["same", "toggle", "cut", "moved"]), min_size=3, max_size=6))
def test_repeated_exact_steps_read_the_field_and_match_the_reference(case, steps):
    """A drag repeats pulls against the same fixed elements: from the second pull out of reach on, the step
    clamps the target with the field of the fixed elements instead of finding it by its walk. Fixed
    elements toggled, links cut or a fixed element moved in between must be noticed: every step keeps every
    link inside, stops where the reference stops and moves no element further than the reference."""
    rest, links, alive, _, fixed, grabbed, targets, order, _, rng = case
    graph, mats, ws, _ = setup(case)
    fixed = np.zeros(len(rest), bool) if fixed is None else fixed.copy()
    fixed[rng.integers(len(rest))] = True
    g, t = grabbed[:1], targets[:1] * 3.0  # one grabbed element, far: out of reach of the fixed ones
    start = rest.copy()
    for what in ["same"] + steps:
        if what == "toggle":
            fixed[rng.integers(len(rest))] ^= True
        elif what == "cut" and len(links):
            graph.cut(rng.choice(len(links), size=1))
        elif what == "moved":  # the fixed elements put elsewhere, every link still inside: a translation
            start = start + 0.37
        pos = start.copy()
        exact_move(rest, pos, graph, *mats, g, t, fixed, ws, order=order)
        ref_start = start.copy()
        moved, _ = cascade(rest, ref_start, graph, *mats, g, t, fixed=fixed, order=order)
        ref, ref_short = ref_exact(rest, ref_start, links, graph.alive, *mats, g, t, fixed)
        scale = 1.0 + np.abs(ref).max()
        assert violations(rest, pos, graph, *mats).outside == 0
        np.testing.assert_array_equal(pos[fixed], start[fixed])
        short = 0.0 if fixed[g[0]] else float(np.linalg.norm(pos[g[0]] - t[0]))
        assert short == pytest.approx(ref_short, abs=1e-7 * scale)
        assert np.all(np.abs(pos - start) <= np.abs(ref - start) + 1e-7 * scale)

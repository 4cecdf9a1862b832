"""Generalised ChainMail cascade (thesis 5.2) against the plain-Python waiting-list reference, plus the
invariants a user relies on: valid regions w.r.t. sponsors, one move per element, untouched elements
bit-identical, anchors never move, no NaN."""

from __future__ import annotations

import numpy as np
import pytest
from cascade_reference import MESH_KINDS, box, random_mesh, ref_cascade
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from chainsim.systems.engine.kernels.chainmail import (
    ORDER_BALANCED,
    ORDER_BREADTH_FIRST,
    ORDER_DEPTH_FIRST,
    ORDER_SCHILL,
    cascade,
    make_workspace,
    material_arrays,
)
from chainsim.systems.engine.kernels.graph import build_graph

SETTINGS = settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])

ORDERS = (ORDER_BREADTH_FIRST, ORDER_BALANCED, ORDER_SCHILL, ORDER_DEPTH_FIRST)


@st.composite
def scenarios(draw):
    kind = draw(st.sampled_from(MESH_KINDS))
    dim = {"planar": 2, "surface": 3, "volume": 3}.get(kind) or draw(st.integers(1, 3))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    rest, links = random_mesh(kind, dim, rng, size=draw(st.integers(3, 7)))
    n, m = len(rest), len(links)
    if draw(st.booleans()):  # per-link materials: inhomogeneous tissue
        amin = rng.uniform(0.0, 1.0, m)
        amax = rng.uniform(1.0, 3.0, m)
        beta = rng.uniform(0.0, 0.6, m)
    else:
        amin, amax, beta = draw(st.sampled_from([(1.0, 1.0, 0.0), (0.8, 1.2, 0.1), (0.5, 2.5, 0.3), (0.0, 4.0, 1.0)]))
    # start from the rest shape or from an earlier deformation
    pos = rest.copy() if draw(st.booleans()) else rest + rng.normal(scale=0.3, size=rest.shape)
    k = draw(st.integers(1, 3))
    grabbed = rng.choice(n, size=min(k, n), replace=False).astype(np.int64)
    scale = draw(st.sampled_from([0.1, 1.0, 5.0]))
    targets = pos[grabbed] + rng.normal(scale=scale, size=(len(grabbed), dim))
    fixed = rng.random(n) < 0.1 if draw(st.booleans()) else None
    alive = rng.random(m) > 0.1 if draw(st.booleans()) else np.ones(m, bool)
    return rest, pos, links, alive, (amin, amax, beta), grabbed, targets, fixed


def run_kernel(rest, pos, links, alive, mats, grabbed, targets, fixed, order, depth=2, workspace=None):
    graph = build_graph(len(rest), links)
    graph.set_alive(~np.asarray(alive, bool), False)
    amin, amax, beta = material_arrays(len(links), *mats)
    p = pos.copy()
    moved, sponsor = cascade(
        rest, p, graph, amin, amax, beta, grabbed, targets, fixed=fixed, order=order, workspace=workspace, depth=depth
    )
    return p, moved, sponsor


@SETTINGS
@given(scenarios(), st.sampled_from(ORDERS), st.integers(1, 3))
def test_kernel_matches_reference(case, order, depth):
    rest, pos, links, alive, mats, grabbed, targets, fixed = case
    p, moved, sponsor = run_kernel(rest, pos, links, alive, mats, grabbed, targets, fixed, order, depth)
    amin, amax, beta = material_arrays(len(links), *mats)
    rp, rmoved, rsponsor = ref_cascade(
        rest, pos, links, alive, amin, amax, beta, grabbed, targets, fixed, order=order, depth=depth
    )
    np.testing.assert_array_equal(moved, rmoved)
    np.testing.assert_array_equal(sponsor, rsponsor)
    np.testing.assert_array_equal(p, rp)


def check_invariants(rest, before, after, links, alive, mats, grabbed, targets, fixed, moved, sponsor, tol=0.0):
    n = len(rest)
    amin, amax, beta = material_arrays(len(links), *mats)
    assert np.all(np.isfinite(after))
    assert len(np.unique(moved)) == len(moved), "an element moved twice"
    free_grabbed = [g for g in grabbed if fixed is None or not fixed[g]]
    k = len(free_grabbed)
    np.testing.assert_array_equal(moved[:k], free_grabbed)
    assert np.all(sponsor[:k] == -1) and np.all(sponsor[k:] >= 0)
    np.testing.assert_array_equal(
        after[moved[:k]], np.asarray(targets, after.dtype)[[list(grabbed).index(g) for g in free_grabbed]]
    )
    if fixed is not None:
        assert not np.any(fixed[moved])
    untouched = np.ones(n, bool)
    untouched[moved] = False
    assert after[untouched].tobytes() == before[untouched].tobytes()
    link_of = {}
    for lid, (u, v) in enumerate(links.tolist()):
        if alive[lid]:
            link_of.setdefault((u, v), lid)
            link_of.setdefault((v, u), lid)
    rank = {e: i for i, e in enumerate(moved.tolist())}
    for e, s in zip(moved[k:].tolist(), sponsor[k:].tolist()):
        assert rank[s] < rank[e], "sponsor must have moved first"
        lid = link_of[(s, e)]  # KeyError: sponsor is not linked to the element by a live link
        for a in range(rest.shape[1]):
            lo, hi = box(rest, after, e, s, a, amin[lid], amax[lid], beta[lid])
            slack = tol * (1.0 + abs(lo) + abs(hi))
            assert lo - slack <= float(after[e, a]) <= hi + slack


@SETTINGS
@given(scenarios(), st.sampled_from(ORDERS))
def test_cascade_invariants(case, order):
    rest, pos, links, alive, mats, grabbed, targets, fixed = case
    p, moved, sponsor = run_kernel(rest, pos, links, alive, mats, grabbed, targets, fixed, order)
    check_invariants(rest, pos, p, links, alive, mats, grabbed, targets, fixed, moved, sponsor)


@settings(max_examples=30, deadline=None)
@given(scenarios())
def test_float32_mode_matches_reference_in_float32(case):
    rest, pos, links, alive, mats, grabbed, targets, fixed = case
    rest32 = rest.astype(np.float32)
    pos32 = pos.astype(np.float32)
    t32 = targets.astype(np.float32)
    p, moved, sponsor = run_kernel(rest32, pos32, links, alive, mats, grabbed, t32, fixed, ORDER_BREADTH_FIRST)
    assert p.dtype == np.float32
    amin, amax, beta = material_arrays(len(links), *mats)
    rp, rmoved, rsponsor = ref_cascade(rest32, pos32, links, alive, amin, amax, beta, grabbed, t32, fixed)
    np.testing.assert_array_equal(moved, rmoved)
    np.testing.assert_array_equal(sponsor, rsponsor)
    np.testing.assert_array_equal(p, rp)
    check_invariants(rest32, pos32, p, links, alive, mats, grabbed, t32, fixed, moved, sponsor, tol=1e-6)


@settings(max_examples=25, deadline=None)
@given(st.lists(scenarios(), min_size=2, max_size=4), st.sampled_from(ORDERS))
def test_workspace_reuse_gives_fresh_results(cases, order):
    """A stale stamp from an earlier cascade must never hide an element from a later one."""
    for rest, pos, links, alive, mats, grabbed, targets, fixed in cases:
        ws = make_workspace(len(rest))
        for _ in range(3):
            p1, m1, s1 = run_kernel(rest, pos, links, alive, mats, grabbed, targets, fixed, order, workspace=ws)
            p2, m2, s2 = run_kernel(rest, pos, links, alive, mats, grabbed, targets, fixed, order)
            np.testing.assert_array_equal(p1, p2)
            np.testing.assert_array_equal(m1, m2)
            np.testing.assert_array_equal(s1, s2)


def test_dead_links_and_anchors_stop_the_cascade():
    rest, links = np.arange(6, dtype=np.float64).reshape(6, 1), np.array([[i, i + 1] for i in range(5)])
    graph = build_graph(6, links)
    mats = material_arrays(5, 1.0, 1.0, 0.0)
    pos = rest.copy()
    graph.cut([2])  # link 2-3
    moved, _ = cascade(rest, pos, graph, *mats, np.array([0]), np.array([[-1.0]]))
    assert sorted(moved.tolist()) == [0, 1, 2]
    np.testing.assert_array_equal(pos[:, 0], [-1, 0, 1, 3, 4, 5])
    graph.set_alive([2], True)
    pos = rest.copy()
    fixed = np.zeros(6, bool)
    fixed[4] = True
    moved, _ = cascade(rest, pos, graph, *mats, np.array([0]), np.array([[-1.0]]), fixed=fixed)
    assert sorted(moved.tolist()) == [0, 1, 2, 3]
    assert pos[4, 0] == 4 and pos[5, 0] == 5


def test_fifo_spreads_breadth_first_on_a_chain():
    rest, links = np.arange(5, dtype=np.float64).reshape(5, 1), np.array([[i, i + 1] for i in range(4)])
    graph = build_graph(5, links)
    pos = rest.copy()
    moved, sponsor = cascade(rest, pos, graph, *material_arrays(4, 0.5, 2.0, 0.0), np.array([2]), np.array([[10.0]]))
    # behind the move the chain stretches to twice its rest gaps, ahead of it it compresses to half
    assert moved.tolist() == [2, 1, 3, 0, 4]
    assert sponsor.tolist() == [-1, 2, 2, 1, 3]
    np.testing.assert_array_equal(pos[:, 0], [6.0, 8.0, 10.0, 10.5, 11.0])


def test_element_inside_its_region_does_not_move_or_propagate():
    rest = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    graph = build_graph(3, np.array([[0, 1], [1, 2]]))
    pos = rest.copy()
    moved, _ = cascade(rest, pos, graph, *material_arrays(2, 0.5, 2.0, 0.5), np.array([0]), np.array([[0.2, 0.3]]))
    assert moved.tolist() == [0]
    np.testing.assert_array_equal(pos[1:], rest[1:])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(alpha_min=1.5), "alpha_min"),
        (dict(alpha_min=-0.1), "alpha_min"),
        (dict(alpha_max=0.9), "alpha_max"),
        (dict(beta=-1.0), "beta"),
        (dict(beta=float("nan")), "beta"),
        (dict(alpha_max=float("inf")), "alpha_max"),
        (dict(alpha_min=np.ones(3)), "alpha_min"),
    ],
)
def test_material_validation(kwargs, match):
    args = dict(alpha_min=0.5, alpha_max=2.0, beta=0.1) | kwargs
    with pytest.raises(ValueError, match=match):
        material_arrays(4, args["alpha_min"], args["alpha_max"], args["beta"])


def test_material_arrays_per_link_and_dtype():
    amin, amax, beta = material_arrays(3, [0.0, 0.5, 1.0], 2.0, 0.25, dtype=np.float32)
    assert amin.dtype == amax.dtype == beta.dtype == np.float32
    np.testing.assert_array_equal(amin, [0.0, 0.5, 1.0])
    np.testing.assert_array_equal(amax, [2.0, 2.0, 2.0])


def test_bad_cascade_arguments_raise():
    rest = np.zeros((3, 2))
    graph = build_graph(3, np.array([[0, 1], [1, 2]]))
    mats = material_arrays(2, 1.0, 1.0, 0.0)
    with pytest.raises(ValueError, match="distinct"):
        cascade(rest, rest.copy(), graph, *mats, np.array([1, 1]), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="grabbed"):
        cascade(rest, rest.copy(), graph, *mats, np.array([3]), np.zeros((1, 2)))
    with pytest.raises(ValueError, match="finite"):
        cascade(rest, rest.copy(), graph, *mats, np.array([0]), np.array([[np.nan, 0.0]]))
    with pytest.raises(ValueError, match="dtype"):
        cascade(rest, rest.astype(np.float32), graph, *mats, np.array([0]), np.zeros((1, 2)))
    with pytest.raises(ValueError, match="per-link"):
        cascade(rest, rest.copy(), graph, np.ones(5), *mats[1:], np.array([0]), np.zeros((1, 2)))
    with pytest.raises(ValueError, match="order"):
        cascade(rest, rest.copy(), graph, *mats, np.array([0]), np.zeros((1, 2)), order=7)


def test_depth_first_puts_new_neighbours_at_the_front():
    """5.2.3 step 3.3 read literally: a moved element's neighbours go to the front of the waiting list,
    so the first branch runs to its end before the grabbed element's second neighbour is checked."""
    rest, links = np.arange(5, dtype=np.float64).reshape(5, 1), np.array([[i, i + 1] for i in range(4)])
    graph = build_graph(5, links)
    mats = material_arrays(4, 0.5, 2.0, 0.0)
    pos = rest.copy()
    moved, sponsor = cascade(rest, pos, graph, *mats, np.array([2]), np.array([[10.0]]), order=ORDER_DEPTH_FIRST)
    assert moved.tolist() == [2, 1, 0, 3, 4]
    assert sponsor.tolist() == [-1, 2, 1, 2, 3]
    pos_bf = rest.copy()
    cascade(rest, pos_bf, graph, *mats, np.array([2]), np.array([[10.0]]), order=ORDER_BREADTH_FIRST)
    np.testing.assert_array_equal(pos, pos_bf)  # on a chain only the visiting order differs

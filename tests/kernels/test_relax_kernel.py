"""Relaxation (thesis 5.2.5) against a numpy Jacobi reference; rigid motions are at rest; results do not
depend on the number of threads."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from cascade_reference import MESH_KINDS, random_mesh
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.systems.engine.kernels.chainmail import cascade, material_arrays
from chainsim.systems.engine.kernels.graph import build_graph
from chainsim.systems.engine.kernels.relax import relax


def numpy_relax(rest, pos, links, alive, active, iterations, step, fixed):
    """Jacobi sweeps written with whole-array numpy operations over the live links."""
    pos = pos.astype(np.float64)
    rest = rest.astype(np.float64)
    live = links[alive]
    a, b = live[:, 0], live[:, 1]
    is_active = np.zeros(len(pos), bool)
    is_active[active] = True
    if fixed is not None:
        is_active &= ~fixed
    for _ in range(iterations):
        acc = np.zeros_like(pos)
        cnt = np.zeros(len(pos))
        # ideal position of a seen from b: b's position plus a's rest offset from b, and vice versa
        np.add.at(acc, a, pos[b] + (rest[a] - rest[b]))
        np.add.at(acc, b, pos[a] + (rest[b] - rest[a]))
        np.add.at(cnt, a, 1.0)
        np.add.at(cnt, b, 1.0)
        upd = is_active & (cnt > 0)
        target = acc[upd] / cnt[upd, None]
        pos[upd] = pos[upd] + step * (target - pos[upd])
    return pos


@st.composite
def relax_cases(draw):
    kind = draw(st.sampled_from(MESH_KINDS))
    dim = {"planar": 2, "surface": 3, "volume": 3}.get(kind) or draw(st.integers(1, 3))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    rest, links = random_mesh(kind, dim, rng, size=draw(st.integers(3, 6)))
    pos = rest + rng.normal(scale=0.5, size=rest.shape)
    active = rng.choice(len(rest), size=draw(st.integers(1, len(rest))), replace=False).astype(np.int64)
    alive = rng.random(len(links)) > 0.15
    fixed = rng.random(len(rest)) < 0.2 if draw(st.booleans()) else None
    iterations = draw(st.integers(0, 6))
    step = draw(st.sampled_from([1.0, 0.5, 0.1]))
    return rest, pos, links, alive, active, iterations, step, fixed


@settings(max_examples=50, deadline=None)
@given(relax_cases())
def test_relax_matches_numpy_reference(case):
    rest, pos, links, alive, active, iterations, step, fixed = case
    graph = build_graph(len(rest), links)
    graph.cut(~np.asarray(alive, bool))
    p = pos.copy()
    relax(rest, p, graph, active, iterations, step=step, fixed=fixed)
    expected = numpy_relax(rest, pos, links, alive, active, iterations, step, fixed)
    np.testing.assert_allclose(p, expected, rtol=1e-12, atol=1e-12)
    untouched = np.ones(len(rest), bool)
    untouched[active] = False
    if fixed is not None:
        untouched |= fixed
    assert p[untouched].tobytes() == pos[untouched].tobytes()


@pytest.mark.parametrize("kind, dim", [("curve", 1), ("planar", 2), ("surface", 3), ("volume", 3)])
def test_rigid_motion_is_already_relaxed(kind, dim):
    rest, links = random_mesh(kind, dim, np.random.default_rng(1))
    graph = build_graph(len(rest), links)
    shift = np.linspace(3.0, -2.0, dim)
    pos = rest + shift
    relax(rest, pos, graph, np.arange(len(rest)), 20)
    np.testing.assert_allclose(pos, rest + shift, atol=1e-12)


def test_relaxation_lowers_the_energy_after_a_cascade():
    rest, links = random_mesh("volume", 3, np.random.default_rng(2), size=8)
    graph = build_graph(len(rest), links)
    pos = rest.copy()
    grab = np.array([0])
    moved, _ = cascade(rest, pos, graph, *material_arrays(len(links), 0.5, 2.0, 0.3), grab, rest[[0]] + 2.0)

    def energy(p):
        d = (p[links[:, 1]] - p[links[:, 0]]) - (rest[links[:, 1]] - rest[links[:, 0]])
        return float(np.sum(d * d))

    before = energy(pos)
    fixed = np.zeros(len(rest), bool)
    fixed[grab] = True
    relax(rest, pos, graph, moved, 10, step=0.5, fixed=fixed)
    assert energy(pos) < before
    np.testing.assert_array_equal(pos[0], rest[0] + 2.0)


def test_result_does_not_depend_on_thread_count():
    rest, links = random_mesh("volume", 3, np.random.default_rng(3), size=10)
    graph = build_graph(len(rest), links)
    pos = rest + np.random.default_rng(4).normal(scale=0.4, size=rest.shape)
    active = np.arange(0, len(rest), 2)
    results = []
    original = numba.get_num_threads()
    try:
        for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
            numba.set_num_threads(threads)
            p = pos.copy()
            relax(rest, p, graph, active, 8, step=0.7)
            results.append(p)
    finally:
        numba.set_num_threads(original)
    assert results[0].tobytes() == results[1].tobytes()


def test_float32_relax():
    rest64, links = random_mesh("surface", 3, np.random.default_rng(5))
    rest = rest64.astype(np.float32)
    graph = build_graph(len(rest), links)
    pos = (rest64 + 0.3).astype(np.float32)
    pos[::3] += np.float32(0.2)
    expected = numpy_relax(rest, pos, links, graph.alive, np.arange(len(rest)), 3, 1.0, None)
    relax(rest, pos, graph, np.arange(len(rest)), 3)
    assert pos.dtype == np.float32
    np.testing.assert_allclose(pos, expected, atol=1e-5)


def test_bad_relax_arguments_raise():
    rest = np.zeros((3, 2))
    graph = build_graph(3, np.array([[0, 1], [1, 2]]))
    with pytest.raises(ValueError, match="step"):
        relax(rest, rest.copy(), graph, np.array([1]), 2, step=1.5)
    with pytest.raises(ValueError, match="active"):
        relax(rest, rest.copy(), graph, np.array([5]), 2)
    with pytest.raises(ValueError, match="rest"):
        relax(rest.astype(np.float32), rest.copy(), graph, np.array([1]), 2)

"""Stability of the cascade at extreme materials, scales and degenerate meshes, and under long
interactive dragging from the current deformed state."""

from __future__ import annotations

import numpy as np
import pytest
from cascade_reference import box, random_mesh, ref_cascade

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
from chainsim.systems.engine.kernels.graph import build_graph, components

ORDERS = (ORDER_BREADTH_FIRST, ORDER_BALANCED, ORDER_SCHILL, ORDER_DEPTH_FIRST)


def meshes():
    rng = np.random.default_rng(7)
    yield "curve1d", random_mesh("curve", 1, rng)
    yield "curve3d", random_mesh("curve", 3, rng)
    yield "planar", random_mesh("planar", 2, rng)
    yield "surface", random_mesh("surface", 3, rng)
    yield "volume", random_mesh("volume", 3, rng, size=8)
    pos, links = random_mesh("random", 2, rng)
    yield "random", (pos, links)


MESHES = dict(meshes())


def assert_valid_wrt_sponsors(rest, pos, graph, mats, moved, sponsor, rel=0.0):
    amin, amax, beta = mats
    link_of = {(int(u), int(v)): i for i, (u, v) in enumerate(graph.links)}
    link_of |= {(v, u): i for (u, v), i in list(link_of.items())}
    for e, s in zip(moved.tolist(), sponsor.tolist()):
        if s < 0:
            continue
        lid = link_of[(s, e)]
        for a in range(rest.shape[1]):
            lo, hi = box(rest, pos, e, s, a, amin[lid], amax[lid], beta[lid])
            slack = rel * max(abs(lo), abs(hi), 1e-300)
            assert lo - slack <= pos[e, a] <= hi + slack


@pytest.mark.parametrize("name", list(MESHES))
@pytest.mark.parametrize("order", ORDERS)
def test_rigid_material_translates_the_whole_connected_mesh(name, order):
    rest, links = MESHES[name]
    graph = build_graph(len(rest), links)
    label = components(graph)
    pos = rest.copy()
    grab = 3
    shift = np.linspace(0.7, -1.3, rest.shape[1])
    moved, _ = cascade(
        rest,
        pos,
        graph,
        *material_arrays(len(links), 1, 1, 0),
        np.array([grab]),
        (rest[grab] + shift)[None],
        order=order,
    )
    same = label == label[grab]
    assert set(moved.tolist()) == set(np.flatnonzero(same).tolist())
    np.testing.assert_allclose(pos[same], rest[same] + shift, rtol=0, atol=1e-12)
    assert pos[~same].tobytes() == rest[~same].tobytes()


@pytest.mark.parametrize("name", list(MESHES))
@pytest.mark.parametrize("order", ORDERS)
def test_extreme_soft_material_stays_finite_and_valid(name, order):
    rest, links = MESHES[name]
    graph = build_graph(len(rest), links)
    mats = material_arrays(len(links), 0.0, 1e12, 1e12)
    pos = rest.copy()
    moved, sponsor = cascade(rest, pos, graph, *mats, np.array([0, 5]), rest[[0, 5]] + 3.0, order=order)
    assert np.all(np.isfinite(pos))
    assert_valid_wrt_sponsors(rest, pos, graph, mats, moved, sponsor)
    # and a collapse: alpha_min = 0 lets a neighbour sit exactly on its sponsor
    mats = material_arrays(len(links), 0.0, 1.0, 0.0)
    pos = rest.copy()
    moved, sponsor = cascade(rest, pos, graph, *mats, np.array([0]), rest[[0]] + 50.0, order=order)
    assert np.all(np.isfinite(pos))
    assert_valid_wrt_sponsors(rest, pos, graph, mats, moved, sponsor)


@pytest.mark.parametrize("link_length", [1e-12, 1.0, 1e6])
@pytest.mark.parametrize("displacement", [1.0, 1e8])
@pytest.mark.parametrize("material", [(1.0, 1.0, 0.0), (0.5, 2.5, 0.3)])
def test_scales_from_tiny_links_to_huge_drags(link_length, displacement, material):
    rest0, links = MESHES["volume"]
    rest = rest0 * link_length
    graph = build_graph(len(rest), links)
    mats = material_arrays(len(links), *material)
    pos = rest.copy()
    shift = np.array([1.0, -0.5, 0.25]) * displacement * link_length
    moved, sponsor = cascade(rest, pos, graph, *mats, np.array([10]), (rest[10] + shift)[None])
    assert np.all(np.isfinite(pos))
    assert_valid_wrt_sponsors(rest, pos, graph, mats, moved, sponsor, rel=1e-15)
    if material == (1.0, 1.0, 0.0):
        assert len(moved) == len(rest)
        scale = np.abs(rest).max() + np.abs(shift).max()
        np.testing.assert_allclose(pos, rest + shift, rtol=0, atol=4 * np.finfo(float).eps * scale)


def test_zero_length_links_and_duplicate_points():
    # a chain with every element doubled at the same place, linked to its twin by zero-length links
    base = np.arange(6, dtype=np.float64)
    rest = np.stack([np.repeat(base, 2), np.zeros(12)], axis=1)
    links = (
        [[2 * i, 2 * i + 1] for i in range(6)]
        + [[2 * i, 2 * i + 2] for i in range(5)]
        + [[2 * i + 1, 2 * i + 3] for i in range(5)]
    )
    links = np.array(links)
    graph = build_graph(12, links)
    for mats in [(1.0, 1.0, 0.0), (0.0, 3.0, 0.5), (0.0, 1e12, 1e12)]:
        m = material_arrays(len(links), *mats)
        for order in ORDERS:
            pos = rest.copy()
            moved, sponsor = cascade(rest, pos, graph, *m, np.array([0]), np.array([[-4.0, 2.0]]), order=order)
            assert np.all(np.isfinite(pos))
            assert_valid_wrt_sponsors(rest, pos, graph, m, moved, sponsor)
            if mats == (1.0, 1.0, 0.0):
                np.testing.assert_array_equal(pos, rest + [-4.0, 2.0])
                np.testing.assert_array_equal(pos[0::2], pos[1::2])  # twins stay together


def test_one_dimensional_rigid_and_soft():
    rest, links = meshgen.chain(20, spacing=0.5, dim=1)
    graph = build_graph(20, links)
    pos = rest.copy()
    cascade(rest, pos, graph, *material_arrays(19, 1, 1, 0), np.array([19]), np.array([[20.0]]))
    np.testing.assert_allclose(pos[:, 0], rest[:, 0] + 10.5, atol=1e-13)
    pos = rest.copy()
    m = material_arrays(19, 0.5, 1.5, 0.7)  # beta has no effect in 1-D: no other axis to shear along
    moved, sponsor = cascade(rest, pos, graph, *m, np.array([0]), np.array([[-3.0]]))
    gaps = np.diff(pos[:, 0])
    assert np.all(gaps[: len(moved) - 1] <= 1.5 * 0.5 + 1e-12) and np.all(gaps >= 0.25 - 1e-12)


def test_float32_rigid_and_extremes():
    rest64, links = MESHES["surface"]
    rest = rest64.astype(np.float32)
    graph = build_graph(len(rest), links)
    pos = rest.copy()
    shift = np.array([0.5, 0.25, -1.0], dtype=np.float32)
    moved, _ = cascade(rest, pos, graph, *material_arrays(len(links), 1, 1, 0), np.array([4]), (rest[4] + shift)[None])
    assert pos.dtype == np.float32 and len(moved) == len(rest)
    np.testing.assert_allclose(pos, rest + shift, atol=1e-5)
    pos = rest.copy()
    mats = material_arrays(len(links), 0.0, 1e12, 1e12, dtype=np.float32)
    cascade(rest, pos, graph, *mats, np.array([4]), (rest[4] + 1e8)[None])
    assert np.all(np.isfinite(pos))


def test_hundred_thousand_small_drags_from_the_deformed_state():
    rest, _, links = meshgen.triangulated_grid(8, 8, spacing=1.0, dim=3)
    rest[:, 2] = 0.3 * np.sin(rest[:, 0])
    graph = build_graph(len(rest), links)
    amin, amax, beta = material_arrays(len(links), 0.8, 1.2, 0.1)
    fixed = np.zeros(len(rest), bool)
    fixed[:8] = True  # one edge of the sheet is anchored
    pos = rest.copy()
    ws = make_workspace(len(rest))
    grab = np.array([60], dtype=np.int64)
    steps = 100_000
    angles = np.linspace(0.0, 40 * np.pi, steps)
    path = rest[60] + np.stack([1.5 * np.cos(angles) - 1.5, 1.5 * np.sin(angles), 0.8 * np.sin(3 * angles)], 1)
    orders = ORDERS
    for i in range(steps - 1):
        cascade(
            rest,
            pos,
            graph,
            amin,
            amax,
            beta,
            grab,
            path[i][None],
            fixed=fixed,
            order=orders[i % len(orders)],
            workspace=ws,
            copy=False,
        )
    assert np.all(np.isfinite(pos))
    np.testing.assert_array_equal(pos[fixed], rest[fixed])
    np.testing.assert_array_equal(pos[60], path[-2])
    # the last drag, from the accumulated deformation, still agrees with the reference exactly
    before = pos.copy()
    moved, sponsor = cascade(rest, pos, graph, amin, amax, beta, grab, path[-1][None], fixed=fixed, workspace=ws)
    rp, rmoved, rsponsor = ref_cascade(rest, before, links, graph.alive, amin, amax, beta, grab, path[-1][None], fixed)
    np.testing.assert_array_equal(moved, rmoved)
    np.testing.assert_array_equal(sponsor, rsponsor)
    np.testing.assert_array_equal(pos, rp)
    # no drift or blow-up after 1e5 drags: the 7 x 7 sheet dragged over a radius-3 loop stays near by
    assert np.abs(pos).max() < 20.0

"""A material with no freedom (alpha_min == alpha_max, beta 0) is cascaded along a stored breadth-first
tree once a move repeats; whatever happens between calls (other start positions, elements already where
the cascade would put them, cuts, anchors changed in place, other grabbed ids, float32), every call gives
the plain breadth-first cascade's positions, order and sponsors bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from cascade_reference import MESH_KINDS, random_mesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from chainsim.engine import meshgen
from chainsim.engine.kernels import rigid
from chainsim.engine.kernels.chainmail import ORDER_BREADTH_FIRST, cascade, make_workspace, material_arrays
from chainsim.engine.kernels.graph import build_graph

SETTINGS = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@pytest.fixture(autouse=True)
def _replay_on_small_meshes(monkeypatch):
    monkeypatch.setattr(rigid, "MIN_ELEMENTS", 0)


def _plain(rest, pos, graph, mats, grabbed, targets, fixed):
    """The breadth-first cascade without a workspace (so never replayed)."""
    p = pos.copy()
    order, sponsors = cascade(rest, p, graph, *mats, grabbed, targets, fixed=fixed, order=ORDER_BREADTH_FIRST)
    return p, order, sponsors


@SETTINGS
@given(
    st.integers(0, 2**32 - 1),
    st.sampled_from(MESH_KINDS),
    st.sampled_from([np.float64, np.float32]),
    st.lists(st.sampled_from(["rest", "noise", "again", "cut", "fixed", "grab", "settled"]), min_size=3, max_size=9),
)
def test_replayed_cascade_equals_the_plain_one(seed, kind, dtype, steps):
    rng = np.random.default_rng(seed)
    dim = {"planar": 2, "surface": 3, "volume": 3}.get(kind) or int(rng.integers(1, 4))
    rest, links = random_mesh(kind, dim, rng, size=5)
    rest = rest.astype(dtype)
    n = len(rest)
    graph = build_graph(n, links)
    mats = material_arrays(graph.n_links, 1.0, 1.0, 0.0)
    ws = make_workspace(n)
    pos = rest.copy()
    fixed = None
    grabbed = np.array([int(rng.integers(n))], dtype=np.int64)
    target = (rest[grabbed] + rng.normal(scale=2.0, size=(1, dim))).astype(dtype)
    for step in ["rest"] + steps:
        if step == "rest":
            pos = rest.copy()
        elif step == "noise":
            pos = (rest + rng.normal(scale=0.3, size=rest.shape)).astype(dtype)
        elif step == "cut" and graph.n_links:
            graph.cut(rng.choice(graph.n_links, size=max(1, graph.n_links // 8), replace=False))
        elif step == "fixed":
            if fixed is None:
                fixed = np.zeros(n, dtype=np.bool_)
            fixed[rng.integers(n)] ^= True  # changed in place: the replay must notice
        elif step == "grab":
            k = int(rng.integers(1, 3))
            grabbed = rng.choice(n, size=min(k, n), replace=False).astype(np.int64)
            target = (rest[grabbed] + rng.normal(scale=2.0, size=(len(grabbed), dim))).astype(dtype)
        elif step == "settled":
            # every element already where the cascade puts it but a few: the replay leaves its tree early
            pos, _, _ = _plain(rest, rest.copy(), graph, mats, grabbed, target, fixed)
            pos[rng.integers(n)] += 1.0
        # three calls in a row, so the tree is built (second) and replayed (third), from the same start
        want = _plain(rest, pos, graph, mats, grabbed, target, fixed)
        for _ in range(3):
            p = pos.copy()
            order, sponsors = cascade(
                rest, p, graph, *mats, grabbed, target, fixed=fixed, order=ORDER_BREADTH_FIRST, workspace=ws
            )
            np.testing.assert_array_equal(p, want[0])
            np.testing.assert_array_equal(order, want[1])
            np.testing.assert_array_equal(sponsors, want[2])
        pos = p


def test_a_pull_from_rest_is_replayed_and_translates_the_block():
    rest, _, links = meshgen.tet_grid(5, 5, 5)
    graph = build_graph(len(rest), links)
    mats = material_arrays(graph.n_links, 1.0, 1.0, 0.0)
    ws = make_workspace(len(rest))
    for _ in range(3):
        pos = rest.copy()
        moved, _ = cascade(rest, pos, graph, *mats, [0], rest[0] + [1.0, 2.0, 3.0], workspace=ws)
        assert len(moved) == len(rest)
        np.testing.assert_allclose(pos - rest, np.broadcast_to([1.0, 2.0, 3.0], rest.shape), atol=1e-12)
    assert ws.rigid is not None and ws.rigid.graph is graph  # the tree was built and used


def test_materials_with_freedom_never_use_the_tree():
    rest, _, links = meshgen.tet_grid(4, 4, 4)
    graph = build_graph(len(rest), links)
    ws = make_workspace(len(rest))
    for material in [(0.9, 1.0, 0.0), (1.0, 1.0, 0.1), (1.0, 1.1, 0.0)]:
        mats = material_arrays(graph.n_links, *material)
        for _ in range(3):
            cascade(rest, rest.copy(), graph, *mats, [0], rest[0] + 1.0, workspace=ws)
        assert rigid.rigid_material(graph) is None
    assert ws.rigid is None

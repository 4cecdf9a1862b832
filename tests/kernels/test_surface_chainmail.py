"""SurfaceChainMail (thesis 4.4): normal-offset propagation and the combined move on a cylinder."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.kernels.graph import build_graph
from chainsim.systems.engine.kernels.surface import cylinder, normal_cascade, surface_move, surface_points


def ref_normal_cascade(disp, links, rest_len, grab, target, shear):
    """Waiting-list reference: served one (candidate, mover) pair at a time."""
    disp = disp.copy()
    adj = [[] for _ in disp]
    for lid, (u, v) in enumerate(links.tolist()):
        adj[u].append((v, lid))
        adj[v].append((u, lid))
    disp[grab] = target
    moved = [grab]
    waiting = [(e, grab, lid) for e, lid in adj[grab]]
    while waiting:
        e, s, lid = waiting.pop(0)
        if e in moved:
            continue
        lim = shear * rest_len[lid]
        new = min(max(disp[e], disp[s] - lim), disp[s] + lim)
        if new != disp[e]:
            disp[e] = new
            moved.append(e)
            waiting += [(f, e, l2) for f, l2 in adj[e] if f not in moved]
    return disp, moved


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(0.0, 0.5), st.floats(-5.0, 5.0))
def test_normal_cascade_matches_reference_and_keeps_the_band(seed, shear, target):
    rng = np.random.default_rng(seed)
    pos, _, links = meshgen.triangulated_grid(7, 6, spacing=float(rng.uniform(0.1, 2.0)))
    graph = build_graph(len(pos), links)
    rest_len = np.linalg.norm(pos[links[:, 1]] - pos[links[:, 0]], axis=1)
    disp = rng.normal(scale=0.01, size=len(pos)) if rng.random() < 0.5 else np.zeros(len(pos))
    grab = int(rng.integers(len(pos)))
    expected, ref_moved = ref_normal_cascade(disp, links, rest_len, grab, target, shear)
    moved = normal_cascade(disp, graph, rest_len, np.array([grab]), np.array([target]), shear)
    assert moved.tolist() == ref_moved
    np.testing.assert_array_equal(disp, expected)
    # every follower sits on the edge of the band of an element that moved before it
    rank = {e: i for i, e in enumerate(moved.tolist())}
    for e in moved[1:].tolist():
        edges = [
            abs(abs(disp[e] - disp[f]) - shear * rest_len[lid])
            for lid, (u, v) in enumerate(links.tolist())
            if e in (u, v)
            for f in [v if u == e else u]
            if f in rank and rank[f] < rank[e]
        ]
        assert min(edges) <= 1e-12 * (1 + abs(target))


def test_zero_shear_lifts_the_whole_sheet_and_fixed_rim_holds():
    pos, _, links = meshgen.triangulated_grid(5, 5)
    graph = build_graph(len(pos), links)
    rest_len = np.linalg.norm(pos[links[:, 1]] - pos[links[:, 0]], axis=1)
    disp = np.zeros(len(pos))
    moved = normal_cascade(disp, graph, rest_len, np.array([12]), np.array([0.7]), 0.0)
    assert len(moved) == len(pos)
    np.testing.assert_array_equal(disp, 0.7)
    disp = np.zeros(len(pos))
    fixed = np.zeros(len(pos), bool)
    fixed[:5] = True
    normal_cascade(disp, graph, rest_len, np.array([22]), np.array([1.0]), 0.1, fixed=fixed)
    np.testing.assert_array_equal(disp[:5], 0.0)
    assert disp[22] == 1.0 and np.all(disp >= 0.0) and np.all(disp <= 1.0)


def test_surface_move_on_a_cylinder():
    shape = (12, 6)
    radius = 2.0
    spacing = [np.linspace(0.0, np.pi * radius, 12), np.linspace(0.0, 3.0, 6)]
    uv_rest, links = meshgen.grid(shape, spacing=spacing)
    uv = uv_rest.copy()
    disp = np.zeros(len(uv))
    mapping = cylinder(radius)
    before = surface_points(mapping, uv, disp)
    np.testing.assert_allclose(np.linalg.norm(before[:, :2], axis=1), radius)
    grab = 5 + 12 * 3
    moved_uv, moved_n = surface_move(uv, uv_rest, disp, shape, grab, uv_rest[grab] + [0.3, 0.2], 0.5, 0.8, 1.2, 0.1)
    after = surface_points(mapping, uv, disp)
    assert np.all(np.isfinite(after))
    np.testing.assert_array_equal(uv[grab], uv_rest[grab] + [0.3, 0.2])
    assert disp[grab] == 0.5
    assert 1 < len(moved_n) < len(uv) and len(moved_uv) >= 1
    # an element nothing moved stays exactly where it was on the surface
    still = np.setdiff1d(np.arange(len(uv)), np.union1d(moved_uv, moved_n))
    assert len(still) > 0
    np.testing.assert_array_equal(after[still], before[still])
    # the grabbed element sits 0.5 outside the cylinder
    assert abs(np.linalg.norm(after[grab, :2]) - (radius + 0.5)) < 1e-12

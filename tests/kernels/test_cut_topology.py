"""Cutting (thesis 4.5.2) and link insertion: which links die, and what a cut does to the cascade."""

from __future__ import annotations

import numpy as np
import pytest
from cascade_reference import random_mesh
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.kernels.chainmail import cascade, material_arrays
from chainsim.systems.engine.kernels.graph import build_graph, components, degree
from chainsim.systems.engine.kernels.topology import add_links, cut_path, cut_plane_strip, cut_segment


def segments_cross(a, b, p, q):
    """Proper crossing of segments a-b and p-q, by solving a + s (b - a) = p + t (q - p)."""
    m = np.array([[b[0] - a[0], p[0] - q[0]], [b[1] - a[1], p[1] - q[1]]])
    if abs(np.linalg.det(m)) < 1e-14:
        return False
    s, t = np.linalg.solve(m, p - a)
    return 0.0 < s < 1.0 and 0.0 < t < 1.0


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(["planar", "random"]))
def test_cut_segment_kills_exactly_the_crossing_links(seed, kind):
    rng = np.random.default_rng(seed)
    pos, links = random_mesh(kind, 2, rng, size=6)
    graph = build_graph(len(pos), links)
    graph.cut(rng.random(len(links)) < 0.1)
    alive_before = graph.alive.copy()
    lo, hi = pos.min(axis=0) - 1, pos.max(axis=0) + 1
    p0, p1 = rng.uniform(lo, hi), rng.uniform(lo, hi)
    killed = cut_segment(pos, graph, p0, p1)
    expected = [i for i, (u, v) in enumerate(links) if alive_before[i] and segments_cross(pos[u], pos[v], p0, p1)]
    assert sorted(killed.tolist()) == expected
    assert not np.any(graph.alive[killed])
    survivors = np.setdiff1d(np.arange(len(links)), killed)
    np.testing.assert_array_equal(graph.alive[survivors], alive_before[survivors])


def test_cut_path_is_the_union_of_its_segments():
    pos, links = random_mesh("planar", 2, np.random.default_rng(3), size=7)
    pts = np.array([[-1.0, 0.3], [2.2, 3.1], [4.7, 1.4], [6.5, 5.2]])
    g1 = build_graph(len(pos), links)
    k1 = cut_path(pos, g1, pts)
    g2 = build_graph(len(pos), links)
    k2 = np.concatenate([cut_segment(pos, g2, pts[i], pts[i + 1]) for i in range(3)])
    assert len(k1) > 0 and sorted(k1.tolist()) == sorted(k2.tolist())
    np.testing.assert_array_equal(g1.alive, g2.alive)


def split_sheet(dim, cut_x):
    pos, _, links = meshgen.triangulated_grid(8, 6, dim=dim)
    graph = build_graph(len(pos), links)
    if dim == 2:
        cut_segment(pos, graph, [cut_x, -1.0], [cut_x, 7.0])
    else:
        cut_plane_strip(pos, graph, [cut_x, -1.0, 0.0], [cut_x, 7.0, 0.0], [0.0, 0.0, 1.0], depth=0.5)
    return pos, links, graph


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("cut_x", [3.5, 3.0, 3.37])
def test_a_cut_across_a_sheet_lets_one_half_move_without_the_other(dim, cut_x):
    pos, links, graph = split_sheet(dim, cut_x)
    label = components(graph)
    assert len(np.unique(label)) == 2  # a cut through a grid line of elements splits it cleanly too
    right = pos[:, 0] > cut_x
    assert len(np.unique(label[right])) == 1 and len(np.unique(label[pos[:, 0] < cut_x])) == 1
    rest = pos.copy()
    p = pos.copy()
    grab = int(np.flatnonzero(right)[0])
    shift = np.full(dim, 2.0)
    moved, _ = cascade(
        rest, p, graph, *material_arrays(len(links), 1, 1, 0), np.array([grab]), (rest[grab] + shift)[None]
    )
    moved_mask = np.zeros(len(p), bool)
    moved_mask[moved] = True
    np.testing.assert_array_equal(moved_mask, label == label[grab])
    assert p[~moved_mask].tobytes() == rest[~moved_mask].tobytes()
    np.testing.assert_allclose(p[moved_mask], rest[moved_mask] + shift, atol=1e-12)


def test_suturing_with_add_links_rejoins_the_halves():
    pos, links, graph = split_sheet(2, 3.5)
    m = len(links)
    dead = np.flatnonzero(~graph.alive)
    stitches = np.array([[i, i + 1] for i in range(3, 48, 8)])  # horizontal links across x = 3.5
    joined = add_links(graph, stitches)
    assert joined.n_links == m + len(stitches)
    np.testing.assert_array_equal(joined.links[:m], graph.links)
    assert not np.any(joined.alive[dead]) and np.all(joined.alive[m:])
    assert len(np.unique(components(joined))) == 1
    p = pos.copy()
    moved, _ = cascade(pos, p, joined, *material_arrays(joined.n_links, 1, 1, 0), np.array([0]), (pos[0] + 1.0)[None])
    assert len(moved) == len(pos)
    np.testing.assert_array_equal(degree(joined), degree(graph) + np.bincount(stitches.ravel(), minlength=len(pos)))


def test_plane_strip_cut_of_a_volume_splits_it_and_respects_depth():
    pos, _, links = meshgen.tet_grid(6, 5, 4)
    graph = build_graph(len(pos), links)
    killed = cut_plane_strip(pos, graph, [2.5, -1.0, 10.0], [2.5, 10.0, 10.0], [0.0, 0.0, -1.0], depth=None)
    assert len(np.unique(components(graph))) == 2
    a, b = pos[links[:, 0], 0], pos[links[:, 1], 0]
    np.testing.assert_array_equal(np.sort(killed), np.flatnonzero((a < 2.5) != (b < 2.5)))
    # a shallow one-sided blade only reaches the top layer of links
    graph = build_graph(len(pos), links)
    killed = cut_plane_strip(
        pos, graph, [2.5, -1.0, 3.0], [2.5, 10.0, 3.0], [0.0, 0.0, -1.0], depth=0.6, two_sided=False
    )
    za, zb = pos[links[killed, 0], 2], pos[links[killed, 1], 2]
    assert len(killed) > 0 and np.all(np.maximum(za, zb) >= 3.0 - 1e-12) and np.all(np.minimum(za, zb) >= 2.0)
    assert len(np.unique(components(graph))) == 1


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_plane_strip_matches_brute_force(seed):
    rng = np.random.default_rng(seed)
    pos, links = random_mesh("surface", 3, rng, size=6)
    graph = build_graph(len(pos), links)
    p0, p1 = rng.uniform(-1, 7, 3), rng.uniform(-1, 7, 3)
    normal = rng.normal(size=3)
    depth = float(rng.uniform(0.2, 3.0))
    killed = cut_plane_strip(pos, graph, p0, p1, normal, depth=depth)
    u = p1 - p0
    n = normal - normal @ u / (u @ u) * u
    n /= np.linalg.norm(n)
    expected = []
    for i, (a, b) in enumerate(links):
        # solve pos[a] + r (pos[b] - pos[a]) = p0 + s u + t n
        m = np.stack([pos[b] - pos[a], -u, -n], axis=1)
        if abs(np.linalg.det(m)) < 1e-12:
            continue
        r, s, t = np.linalg.solve(m, p0 - pos[a])
        if 0 < r < 1 and 0 < s < 1 and -depth < t < depth:
            expected.append(i)
    assert sorted(killed.tolist()) == expected


def test_cut_segment_in_3d_uses_the_blade_normal():
    pos, _, links = meshgen.triangulated_grid(6, 6, dim=3)
    graph = build_graph(len(pos), links)
    killed = cut_segment(pos, graph, [2.5, -1.0, 0.0], [2.5, 9.0, 0.0])  # default normal +z
    assert len(killed) > 0 and len(np.unique(components(graph))) == 2
    graph = build_graph(len(pos), links)
    assert len(cut_segment(pos, graph, [2.5, -1.0, 5.0], [2.5, 9.0, 5.0], normal=[0, 0, 1], depth=1.0)) == 0


def test_bad_cut_arguments_raise():
    pos, _, links = meshgen.triangulated_grid(3, 3, dim=3)
    graph = build_graph(len(pos), links)
    with pytest.raises(ValueError, match="parallel"):
        cut_plane_strip(pos, graph, [0, 0, 0], [1, 0, 0], [2, 0, 0])
    with pytest.raises(ValueError, match="points"):
        cut_path(pos, graph, [[0, 0, 0]])
    with pytest.raises(ValueError, match="new_links"):
        add_links(graph, [[0.5, 1.0]])
    with pytest.raises(ValueError, match="itself"):
        add_links(graph, [[2, 2]])

"""The swept segment-triangle kernel of the needle procedure's collision against a brute-force one (thesis 3.3.6)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.systems.engine.segment_tree import SegmentTree


def brute_first_hit(p0, p1, vertices, triangles):
    """Plain-Python Moller-Trumbore over every triangle: (t, triangle) of the nearest hit in [0, 1]."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    d = p1 - p0
    best, best_i = np.inf, -1
    for i, (a, b, c) in enumerate(vertices[triangles]):
        e1, e2 = b - a, c - a
        p = np.cross(d, e2)
        det = e1 @ p
        if abs(det) < 1e-300:
            continue
        s = p0 - a
        u = (s @ p) / det
        q = np.cross(s, e1)
        v = (d @ q) / det
        t = (e2 @ q) / det
        if u >= -1e-9 and v >= -1e-9 and u + v <= 1 + 1e-9 and 0.0 <= t <= 1.0 and t < best:
            best, best_i = t, i
    return best, best_i


coord = st.floats(-50.0, 50.0, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 300), st.lists(coord, min_size=6, max_size=6))
def test_kernel_matches_brute_force_on_random_soup(seed, n_tri, seg):
    rng = np.random.default_rng(seed)
    vertices = rng.uniform(-40, 40, size=(3 * n_tri, 3))
    # small triangles scattered through space, as well as some big ones
    centres = np.repeat(rng.uniform(-40, 40, size=(n_tri, 3)), 3, axis=0)
    scale = np.repeat(rng.choice([2.0, 10.0, 40.0], size=n_tri), 3)[:, None]
    vertices = centres + (vertices / 40.0) * scale
    triangles = np.arange(3 * n_tri).reshape(-1, 3)
    p0, p1 = np.array(seg[:3]), np.array(seg[3:])
    tree = SegmentTree.build(vertices, triangles)
    t, i = tree.first_hit(p0, p1)
    bt, _ = brute_first_hit(p0, p1, vertices, triangles)
    if np.isinf(bt):
        assert np.isinf(t) and i == -1
    else:
        assert t == pytest.approx(bt, abs=1e-9)
        # ties between coincident hits may pick either triangle; the hit point is what matters
        assert np.allclose(p0 + t * (p1 - p0), p0 + bt * (p1 - p0), atol=1e-7)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.5, 400.0))
def test_no_tunnelling_out_of_a_closed_surface(seed, length):
    """Any segment from inside a closed sphere to outside it meets the surface, however long."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=20.0)
    tree = SegmentTree.build(sphere.vertices, sphere.faces)
    rng = np.random.default_rng(seed)
    start = rng.uniform(-1, 1, 3) * 5.0
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    end = start + d * (30.0 + length)  # |start| < 9: the end is always outside
    t, i = tree.first_hit(start, end)
    assert i >= 0
    hit = start + t * (end - start)
    # on the polyhedral surface: within the sphere radius, beyond the inscribed radius
    assert 19.0 < np.linalg.norm(hit) <= 20.0 + 1e-9


def test_segment_through_a_shared_edge_hits():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    tree = SegmentTree.build(v, tris)
    t, i = tree.first_hit([0.5, 0.5, 1.0], [0.5, 0.5, -1.0])  # exactly on the diagonal
    assert t == pytest.approx(0.5) and i in (0, 1)
    t, i = tree.first_hit([1.0, 1.0, 1.0], [1.0, 1.0, -1.0])  # exactly on a vertex
    assert t == pytest.approx(0.5)


def test_segment_that_stops_short_misses():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)
    tree = SegmentTree.build(v, np.array([[0, 1, 2]]))
    assert tree.first_hit([0.2, 0.2, 1.0], [0.2, 0.2, 0.01])[1] == -1
    assert tree.first_hit([0.2, 0.2, 1.0], [0.2, 0.2, 0.0])[0] == pytest.approx(1.0)

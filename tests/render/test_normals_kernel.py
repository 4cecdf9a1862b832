"""Normal kernels (game/gl/normals.py) against a plain numpy reference on random meshes."""

import numpy as np
from hypothesis import given, settings, strategies as st

from game.gl.normals import patch_normals_kernel, vertex_normals_kernel


def reference_normals(pos, tris):
    pos = np.asarray(pos, np.float64)
    fn = np.cross(pos[tris[:, 1]] - pos[tris[:, 0]], pos[tris[:, 2]] - pos[tris[:, 0]])
    acc = np.zeros_like(pos)
    for c in range(3):
        np.add.at(acc, tris[:, c], fn)
    ln = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.where(ln > 1e-30, acc / np.where(ln > 1e-30, ln, 1.0), 0.0)


def random_mesh(rng, n, f):
    pos = rng.normal(size=(n, 3)) * 10.0
    tris = np.array([rng.choice(n, 3, replace=False) for _ in range(f)], np.int64)
    return pos, tris


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(3, 60), st.integers(1, 120), st.sampled_from([np.float32, np.float64]))
def test_vertex_normals_match_the_reference(seed, n, f, dtype):
    rng = np.random.default_rng(seed)
    pos, tris = random_mesh(rng, n, f)
    pos = pos.astype(dtype)
    out = np.empty((n, 3))
    vertex_normals_kernel(pos, tris, out)
    np.testing.assert_allclose(out, reference_normals(pos, tris), atol=1e-9 if dtype == np.float64 else 1e-5)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(3, 60), st.integers(1, 120), st.integers(1, 10))
def test_patch_normals_equal_the_full_ones_on_the_patch(seed, n, f, k):
    rng = np.random.default_rng(seed)
    pos, tris = random_mesh(rng, n, f)
    verts = np.unique(rng.choice(n, min(k, n), replace=False))
    around = np.flatnonzero(np.isin(tris, verts).any(axis=1))
    local = np.full(n, -1, np.int64)
    out = np.empty((len(verts), 3))
    patch_normals_kernel(pos, tris, around, verts, local, out)
    np.testing.assert_allclose(out, reference_normals(pos, tris)[verts], atol=1e-9)
    assert np.all(local == -1)  # the scratch comes back as it went in

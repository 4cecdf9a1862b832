"""Normal kernels (game/gl/normals.py) against a plain numpy reference on random meshes."""

import numpy as np
from hypothesis import given, settings, strategies as st

from game.gl.normals import moved_normals_kernel, vertex_normals_kernel


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
def test_moved_normals_renew_exactly_the_affected_vertices(seed, n, f, k):
    from game.gl.meshbuf import incidence

    rng = np.random.default_rng(seed)
    pos, tris = random_mesh(rng, n, f)
    before = reference_normals(pos, tris)
    ids = np.sort(rng.choice(n, min(k, n), replace=False)).astype(np.int64)
    pos[ids] += rng.normal(size=(len(ids), 3)) * 3.0
    normals = before.astype(np.float32)
    ptr, idx = incidence(n, tris)
    mark = np.zeros(n, np.bool_)
    verts = moved_normals_kernel(pos, tris, ptr, idx, ids, mark, normals)
    affected = np.union1d(ids, tris[np.isin(tris, ids).any(axis=1)].ravel())
    assert verts.tolist() == affected.tolist()
    np.testing.assert_allclose(normals, reference_normals(pos, tris), atol=1e-5)  # all correct again
    assert not mark.any()  # the scratch comes back as it went in

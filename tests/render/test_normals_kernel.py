"""Normal kernels (game/render/normals.py) against a plain numpy reference on random meshes."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.systems.engine.kernels.normals import moved_normals_kernel, vertex_normals_kernel


def reference_normals(pos, tris):
    """(unit normals, defined): `defined` is False where opposite faces cancel to rounding noise, whose
    direction is arbitrary (a vertex shared by a triangle and its reverse)."""
    pos = np.asarray(pos, np.float64)
    fn = np.cross(pos[tris[:, 1]] - pos[tris[:, 0]], pos[tris[:, 2]] - pos[tris[:, 0]])
    acc = np.zeros_like(pos)
    size = np.zeros(len(pos))
    for c in range(3):
        np.add.at(acc, tris[:, c], fn)
        np.add.at(size, tris[:, c], np.linalg.norm(fn, axis=1))
    ln = np.linalg.norm(acc, axis=1, keepdims=True)
    unit = np.where(ln > 1e-30, acc / np.where(ln > 1e-30, ln, 1.0), 0.0)
    defined = (ln[:, 0] > 1e-6 * size) | (size == 0)
    return unit, defined


def assert_normals(got, pos, tris, atol):
    want, defined = reference_normals(pos, tris)
    np.testing.assert_allclose(got[defined], want[defined], atol=atol)


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
    assert_normals(out, pos, tris, 1e-9 if dtype == np.float64 else 1e-5)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(3, 60), st.integers(1, 120), st.integers(1, 10))
def test_moved_normals_renew_exactly_the_affected_vertices(seed, n, f, k):
    from chainsim.game.render.meshbuf import incidence

    rng = np.random.default_rng(seed)
    pos, tris = random_mesh(rng, n, f)
    before = reference_normals(pos, tris)[0]
    ids = np.sort(rng.choice(n, min(k, n), replace=False)).astype(np.int64)
    pos[ids] += rng.normal(size=(len(ids), 3)) * 3.0
    normals = before.astype(np.float32)
    ptr, idx = incidence(n, tris)
    mark = np.zeros(n, np.bool_)
    verts = moved_normals_kernel(pos, tris, ptr, idx, ids, mark, normals)
    affected = np.union1d(ids, tris[np.isin(tris, ids).any(axis=1)].ravel())
    assert verts.tolist() == affected.tolist()
    assert_normals(normals, pos, tris, 1e-5)  # all correct again
    assert not mark.any()  # the scratch comes back as it went in


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(3, 60), st.integers(1, 120), st.sampled_from([np.float32, np.float64]))
def test_gathered_normals_match_the_reference_and_the_serial_kernel(seed, n, f, dtype):
    """The gathering kernel (each vertex sums its own faces: the parallel path for whole-mesh uploads)
    against the plain reference, and bit for bit against the serial kernel: same sums in the same order."""
    from chainsim.game.render.meshbuf import incidence
    from chainsim.systems.engine.kernels.normals import _gather

    rng = np.random.default_rng(seed)
    pos, tris = random_mesh(rng, n, f)
    pos = pos.astype(dtype)
    got = np.empty((n, 3), np.float32)
    _gather(pos, tris, *incidence(n, tris), got, 0, n)
    assert_normals(got, pos, tris, 1e-9 if dtype == np.float64 else 1e-5)
    serial = np.empty((n, 3))
    vertex_normals_kernel(pos, tris, serial)
    np.testing.assert_array_equal(got, serial.astype(np.float32))


def test_parallel_normals_are_the_same_for_any_thread_count(monkeypatch):
    import numba

    from chainsim.game.render.meshbuf import incidence
    from chainsim.systems.engine.kernels import normals

    monkeypatch.setattr(normals, "PARALLEL_TRIANGLES", 0)
    monkeypatch.setattr(normals, "PARALLEL_THREADS", 2)
    rng = np.random.default_rng(3)
    pos, tris = random_mesh(rng, 400, 1500)
    csr = incidence(400, tris)
    outs = []
    previous = numba.get_num_threads()
    try:
        for threads in (1, numba.config.NUMBA_NUM_THREADS):
            numba.set_num_threads(threads)
            out = np.empty((400, 3))
            normals.normals_into(pos, tris, *csr, out)
            outs.append(out)
    finally:
        numba.set_num_threads(previous)
    np.testing.assert_array_equal(outs[0], outs[1])
    assert_normals(outs[0], pos, tris, 1e-9)

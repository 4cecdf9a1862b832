"""Per-vertex normals of a deformed mesh (numba kernels, thin wrappers in chainsim.game.render.meshbuf).

A vertex normal is the area-weighted sum of the face normals around it (the unnormalised cross
product of two triangle edges), normalised. After a ChainMail move (thesis 5.2.3) only the normals
of the moved vertices' triangles change; `moved_normals_kernel` recomputes just those vertices. When
the whole mesh moved, `normals_into` computes face normals then gathers them per vertex through the
vertex -> triangle incidence, on every thread for big meshes (no two vertices write the same place).
Pure functions on arrays, float64 accumulation; no GL, no ECS.
"""

from __future__ import annotations

import numpy as np
from numba import get_num_threads, njit, prange


@njit(cache=True)
def _normalise_rows(acc, out):
    for i in range(acc.shape[0]):
        x, y, z = acc[i, 0], acc[i, 1], acc[i, 2]
        ln = np.sqrt(x * x + y * y + z * z)
        if ln > 1e-30:
            out[i, 0] = x / ln
            out[i, 1] = y / ln
            out[i, 2] = z / ln
        else:
            out[i, 0] = 0.0
            out[i, 1] = 0.0
            out[i, 2] = 0.0


@njit(cache=True)
def _face_normal(pos, a, b, c):
    ax, ay, az = np.float64(pos[a, 0]), np.float64(pos[a, 1]), np.float64(pos[a, 2])
    ux, uy, uz = pos[b, 0] - ax, pos[b, 1] - ay, pos[b, 2] - az
    vx, vy, vz = pos[c, 0] - ax, pos[c, 1] - ay, pos[c, 2] - az
    return uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx


@njit(cache=True)
def vertex_normals_kernel(pos, tris, out):
    """Unit normals of every vertex into `out` (N, 3) (any float dtype; zero where undefined)."""
    n = pos.shape[0]
    acc = np.zeros((n, 3))
    for t in range(tris.shape[0]):
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        # _face_normal written out: a call passing the array costs more than the cross product
        ax, ay, az = np.float64(pos[a, 0]), np.float64(pos[a, 1]), np.float64(pos[a, 2])
        ux, uy, uz = pos[b, 0] - ax, pos[b, 1] - ay, pos[b, 2] - az
        vx, vy, vz = pos[c, 0] - ax, pos[c, 1] - ay, pos[c, 2] - az
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        acc[a, 0] += nx
        acc[a, 1] += ny
        acc[a, 2] += nz
        acc[b, 0] += nx
        acc[b, 1] += ny
        acc[b, 2] += nz
        acc[c, 0] += nx
        acc[c, 1] += ny
        acc[c, 2] += nz
    _normalise_rows(acc, out)


@njit(cache=True)
def moved_normals_kernel(pos, tris, ptr, idx, ids, mark, normals):
    """Renew `normals` (N, 3) wherever moving vertices `ids` changed them; returns those vertex ids.

    Those are the corners of every triangle with a moved corner; each gets the normalised sum of the
    face normals of all its triangles, found through the CSR incidence `ptr`/`idx` (triangles of v are
    idx[ptr[v]:ptr[v+1]]). `mark` is an (N,) bool scratch of False, returned as it came."""
    bound = 0
    for i in range(ids.shape[0]):
        v = ids[i]
        bound += 3 * (ptr[v + 1] - ptr[v])
    verts = np.empty(bound + ids.shape[0], np.int64)
    count = 0
    for i in range(ids.shape[0]):
        v = ids[i]
        if not mark[v]:
            mark[v] = True
            verts[count] = v
            count += 1
        for j in range(ptr[v], ptr[v + 1]):
            t = idx[j]
            for c in range(3):
                w = tris[t, c]
                if not mark[w]:
                    mark[w] = True
                    verts[count] = w
                    count += 1
    for k in range(count):
        v = verts[k]
        mark[v] = False
        sx, sy, sz = 0.0, 0.0, 0.0
        for j in range(ptr[v], ptr[v + 1]):
            t = idx[j]
            nx, ny, nz = _face_normal(pos, tris[t, 0], tris[t, 1], tris[t, 2])
            sx += nx
            sy += ny
            sz += nz
        ln = np.sqrt(sx * sx + sy * sy + sz * sz)
        if ln > 1e-30:
            normals[v, 0] = sx / ln
            normals[v, 1] = sy / ln
            normals[v, 2] = sz / ln
        else:
            normals[v, 0] = 0.0
            normals[v, 1] = 0.0
            normals[v, 2] = 0.0
    return np.sort(verts[:count])


@njit(cache=True)
def _gather(pos, tris, ptr, idx, out, v_lo, v_hi):
    """Vertices [v_lo, v_hi): the normalised sum of the face normals of their triangles, in CSR order
    (each face normal is computed where it is needed: re-reading three vertices beats storing and
    re-reading a face array that does not fit in cache)."""
    for v in range(v_lo, v_hi):
        sx, sy, sz = 0.0, 0.0, 0.0
        for j in range(ptr[v], ptr[v + 1]):
            t = idx[j]
            a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
            ax, ay, az = np.float64(pos[a, 0]), np.float64(pos[a, 1]), np.float64(pos[a, 2])
            ux, uy, uz = pos[b, 0] - ax, pos[b, 1] - ay, pos[b, 2] - az
            vx, vy, vz = pos[c, 0] - ax, pos[c, 1] - ay, pos[c, 2] - az
            sx += uy * vz - uz * vy
            sy += uz * vx - ux * vz
            sz += ux * vy - uy * vx
        ln = np.sqrt(sx * sx + sy * sy + sz * sz)
        if ln > 1e-30:
            out[v, 0] = sx / ln
            out[v, 1] = sy / ln
            out[v, 2] = sz / ln
        else:
            out[v, 0] = 0.0
            out[v, 1] = 0.0
            out[v, 2] = 0.0


@njit(cache=True, parallel=True)
def _normals_parallel(pos, tris, ptr, idx, out, chunks):
    nv = pos.shape[0]
    step = (nv + chunks - 1) // chunks
    for c in prange(chunks):
        _gather(pos, tris, ptr, idx, out, c * step, min((c + 1) * step, nv))


#: the gathered kernel runs in parallel from this many triangles and this many threads; it does three
#: times the arithmetic of the scatter kernel (each face normal once per corner), so it only pays with
#: several cores to spread it over
PARALLEL_TRIANGLES = 100_000
PARALLEL_THREADS = 4


def normals_into(pos, tris, ptr, idx, out) -> None:
    """Unit vertex normals of the whole mesh into `out` (N, 3) (any float dtype). With enough threads
    each vertex gathers its face normals through the incidence CSR `ptr`/`idx` on its own (no write is
    shared, so every thread works); otherwise the serial scatter kernel runs. Both sum each vertex's
    face normals in the same order, so the result is the same bit for bit either way, for any number
    of threads."""
    threads = get_num_threads()
    if tris.shape[0] >= PARALLEL_TRIANGLES and threads >= PARALLEL_THREADS:
        _normals_parallel(pos, tris, ptr, idx, out, 4 * threads)
    else:
        vertex_normals_kernel(pos, tris, out)

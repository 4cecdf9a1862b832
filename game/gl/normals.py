"""Per-vertex normals of a deformed mesh (numba kernels, thin wrappers in game.gl.meshbuf).

A vertex normal is the area-weighted sum of the face normals around it (the unnormalised cross
product of two triangle edges), normalised. After a ChainMail move (thesis 5.2.3) only the normals
of the moved vertices' triangles change; `patch_normals` recomputes just those vertices.
Pure functions on arrays, float64 accumulation; no GL, no ECS.
"""

from __future__ import annotations

import numpy as np
from numba import njit


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
        nx, ny, nz = _face_normal(pos, a, b, c)
        for v in (a, b, c):
            acc[v, 0] += nx
            acc[v, 1] += ny
            acc[v, 2] += nz
    _normalise_rows(acc, out)


@njit(cache=True)
def patch_normals_kernel(pos, tris, around, verts, local, out):
    """Unit normals of `verts` into `out` (len(verts), 3), from the triangles `around` them.

    `around` must hold every triangle touching a vertex of `verts`; `local` is an (N,) int64 scratch
    filled with -1, returned as it came."""
    for i in range(verts.shape[0]):
        local[verts[i]] = i
    acc = np.zeros((verts.shape[0], 3))
    for k in range(around.shape[0]):
        t = around[k]
        a, b, c = tris[t, 0], tris[t, 1], tris[t, 2]
        nx, ny, nz = _face_normal(pos, a, b, c)
        for v in (a, b, c):
            li = local[v]
            if li >= 0:
                acc[li, 0] += nx
                acc[li, 1] += ny
                acc[li, 2] += nz
    for i in range(verts.shape[0]):
        local[verts[i]] = -1
    _normalise_rows(acc, out)

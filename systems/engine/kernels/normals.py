"""Per-vertex normals of a deformed mesh (numba kernels, thin wrappers in chainsim.game.gl.meshbuf).

A vertex normal is the area-weighted sum of the face normals around it (the unnormalised cross
product of two triangle edges), normalised. After a ChainMail move (thesis 5.2.3) only the normals
of the moved vertices' triangles change; `moved_normals_kernel` recomputes just those vertices.
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

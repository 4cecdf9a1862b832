"""First hit of a line segment on a triangle mesh: a two-level box hierarchy and its numba kernel.

Triangles are sorted along a Morton curve and grouped in chunks of CHUNK with bounding boxes; chunks
are grouped again. The kernel (`segment_first_hit`) culls each level with a slab test clipped to the
best hit found so far, so a swept needle of any length is tested exactly (thesis 3.3.6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

CHUNK = 16
GROUP = 16
BARY_EPS = 1e-9  # inclusive barycentric tolerance: a segment through a shared edge hits one side
BOX_PAD = 1e-6  # mm


# -- kernels -----------------------------------------------------------------------------------------


@njit(cache=True)
def _slab(p0, d, lo, hi, tmax):
    """Whether the segment p0 + t d, t in [0, tmax], meets the box [lo, hi]."""
    t0 = 0.0
    t1 = tmax
    for a in range(3):
        if abs(d[a]) < 1e-300:
            if p0[a] < lo[a] or p0[a] > hi[a]:
                return False
        else:
            inv = 1.0 / d[a]
            ta = (lo[a] - p0[a]) * inv
            tb = (hi[a] - p0[a]) * inv
            if ta > tb:
                ta, tb = tb, ta
            if ta > t0:
                t0 = ta
            if tb < t1:
                t1 = tb
            if t0 > t1:
                return False
    return True


@njit(cache=True)
def _tri_t(p0, d, v0, e1, e2):
    """Moller-Trumbore: the segment parameter of the hit (two-sided), or -1 when missed."""
    px = d[1] * e2[2] - d[2] * e2[1]
    py = d[2] * e2[0] - d[0] * e2[2]
    pz = d[0] * e2[1] - d[1] * e2[0]
    det = e1[0] * px + e1[1] * py + e1[2] * pz
    if abs(det) < 1e-300:
        return -1.0
    inv = 1.0 / det
    sx = p0[0] - v0[0]
    sy = p0[1] - v0[1]
    sz = p0[2] - v0[2]
    u = (sx * px + sy * py + sz * pz) * inv
    if u < -BARY_EPS or u > 1.0 + BARY_EPS:
        return -1.0
    qx = sy * e1[2] - sz * e1[1]
    qy = sz * e1[0] - sx * e1[2]
    qz = sx * e1[1] - sy * e1[0]
    v = (d[0] * qx + d[1] * qy + d[2] * qz) * inv
    if v < -BARY_EPS or u + v > 1.0 + BARY_EPS:
        return -1.0
    return (e2[0] * qx + e2[1] * qy + e2[2] * qz) * inv


@njit(cache=True)
def segment_first_hit(p0, p1, v0, e1, e2, chunk_lo, chunk_hi, group_lo, group_hi, n_tri):
    """(t, i): the smallest t in [0, 1] where p0 + t (p1 - p0) meets triangle i (in sorted order),
    or (inf, -1). Triangles are v0 + a e1 + b e2; chunk c holds triangles [c*CHUNK, (c+1)*CHUNK),
    group g holds chunks [g*GROUP, (g+1)*GROUP)."""
    d = p1 - p0
    best = np.inf
    best_i = -1
    n_chunk = chunk_lo.shape[0]
    for g in range(group_lo.shape[0]):
        lim = best if best < 1.0 else 1.0
        if not _slab(p0, d, group_lo[g], group_hi[g], lim):
            continue
        c_end = min((g + 1) * GROUP, n_chunk)
        for c in range(g * GROUP, c_end):
            lim = best if best < 1.0 else 1.0
            if not _slab(p0, d, chunk_lo[c], chunk_hi[c], lim):
                continue
            t_end = min((c + 1) * CHUNK, n_tri)
            for i in range(c * CHUNK, t_end):
                t = _tri_t(p0, d, v0[i], e1[i], e2[i])
                if t >= 0.0 and t <= 1.0 and t < best:
                    best = t
                    best_i = i
    return best, best_i


# -- precomputed meshes -------------------------------------------------------------------------------


def _morton(c: np.ndarray) -> np.ndarray:
    lo, hi = c.min(0), c.max(0)
    q = ((c - lo) / np.maximum(hi - lo, 1e-9) * 1023).astype(np.uint64)
    code = np.zeros(len(c), dtype=np.uint64)
    for bit in range(10):
        for a in range(3):
            code |= ((q[:, a] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + a)
    return code


@dataclass(slots=True)
class SegmentTree:
    """One mesh prepared for `segment_first_hit` (world millimetres)."""

    v0: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    chunk_lo: np.ndarray
    chunk_hi: np.ndarray
    group_lo: np.ndarray
    group_hi: np.ndarray
    order: np.ndarray  # sorted index -> original triangle index

    @classmethod
    def build(cls, vertices: np.ndarray, triangles: np.ndarray) -> SegmentTree:
        vertices = np.asarray(vertices, dtype=np.float64)
        triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        corners = vertices[triangles]  # (F, 3, 3)
        order = np.argsort(_morton(corners.mean(axis=1)), kind="stable") if len(triangles) else np.zeros(0, np.int64)
        corners = corners[order]
        v0 = np.ascontiguousarray(corners[:, 0])
        e1 = np.ascontiguousarray(corners[:, 1] - corners[:, 0])
        e2 = np.ascontiguousarray(corners[:, 2] - corners[:, 0])
        n = len(corners)
        n_chunk = (n + CHUNK - 1) // CHUNK
        tlo, thi = corners.min(axis=1), corners.max(axis=1)
        chunk_lo = np.empty((n_chunk, 3))
        chunk_hi = np.empty((n_chunk, 3))
        for c in range(n_chunk):
            chunk_lo[c] = tlo[c * CHUNK : (c + 1) * CHUNK].min(0) - BOX_PAD
            chunk_hi[c] = thi[c * CHUNK : (c + 1) * CHUNK].max(0) + BOX_PAD
        n_group = (n_chunk + GROUP - 1) // GROUP
        group_lo = np.empty((n_group, 3))
        group_hi = np.empty((n_group, 3))
        for g in range(n_group):
            group_lo[g] = chunk_lo[g * GROUP : (g + 1) * GROUP].min(0)
            group_hi[g] = chunk_hi[g * GROUP : (g + 1) * GROUP].max(0)
        return cls(v0, e1, e2, chunk_lo, chunk_hi, group_lo, group_hi, order.astype(np.int64))

    def first_hit(self, p0: ArrayLike, p1: ArrayLike) -> tuple[float, int]:
        """(t in [0, 1], original triangle index) of the first hit along p0 -> p1, or (inf, -1)."""
        if len(self.v0) == 0:
            return np.inf, -1
        t, i = segment_first_hit(
            np.asarray(p0, np.float64),
            np.asarray(p1, np.float64),
            self.v0,
            self.e1,
            self.e2,
            self.chunk_lo,
            self.chunk_hi,
            self.group_lo,
            self.group_hi,
            len(self.v0),
        )
        return (float(t), int(self.order[i])) if i >= 0 else (np.inf, -1)

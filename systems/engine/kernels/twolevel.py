"""Kernels of the two-level tissue solve (chainsim.engine.bodies.hybrid): the trilinear map from a coarse
grid to the nodes of a tetrahedral mesh, the rest stiffness of linear elasticity per tetrahedron, and the
front that wakes sleeping nodes when a disturbance reaches them.

All are pure functions on arrays; the body assembles sparse matrices from their output.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def trilinear_weights(points, lo, spacing, dims):
    """For each point (N, 3), the 8 corners of the coarse grid cell holding it (flat ids into a grid of
    `dims` nodes, x fastest) and their trilinear weights (each row sums to 1). A point outside the grid
    is clamped to its nearest cell (its weights then extrapolate, still summing to 1)."""
    n = points.shape[0]
    ids = np.zeros((n, 8), dtype=np.int64)
    w = np.zeros((n, 8))
    cell = np.zeros(3, dtype=np.int64)
    t = np.zeros(3)
    for i in range(n):
        for a in range(3):
            s = (points[i, a] - lo[a]) / spacing
            c = int(np.floor(s))
            c = min(max(c, 0), max(dims[a] - 2, 0))
            cell[a] = c
            t[a] = s - c
        k = 0
        for dz in range(2):
            for dy in range(2):
                for dx in range(2):
                    wx = t[0] if dx else 1.0 - t[0]
                    wy = t[1] if dy else 1.0 - t[1]
                    wz = t[2] if dz else 1.0 - t[2]
                    gx = min(cell[0] + dx, dims[0] - 1)
                    gy = min(cell[1] + dy, dims[1] - 1)
                    gz = min(cell[2] + dz, dims[2] - 1)
                    ids[i, k] = gx + dims[0] * (gy + dims[1] * gz)
                    w[i, k] = wx * wy * wz
                    k += 1
    return ids, w


@njit(cache=True)
def tet_stiffness(D, vol, mu, lam):
    """Element stiffness (T, 12, 12) of linear elasticity, energy V (mu |eps|^2 + lam / 2 tr(eps)^2),
    dof 3 a + i for corner a and axis i; D (T, 4, 3) holds each corner's shape-function gradient (the
    projective body's rest operator). At rest this is the Hessian of the corotational energy, whose
    rotation term vanishes to first order."""
    T = D.shape[0]
    K = np.zeros((T, 12, 12))
    for t in range(T):
        v = vol[t]
        for a in range(4):
            for b in range(4):
                gg = D[t, a, 0] * D[t, b, 0] + D[t, a, 1] * D[t, b, 1] + D[t, a, 2] * D[t, b, 2]
                for i in range(3):
                    for j in range(3):
                        k = lam * D[t, a, i] * D[t, b, j] + mu * D[t, a, j] * D[t, b, i]
                        if i == j:
                            k += mu * gg
                        K[t, 3 * a + i, 3 * b + j] = v * k
    return K


@njit(cache=True)
def wake_front(indptr, indices, awake, change, threshold, rings):
    """Wake the sleeping neighbours (graph CSR indptr/indices) of every awake node whose last change
    exceeds `threshold`, then `rings` - 1 further rings around them; returns how many woke. A wave that
    still moves at the edge of the awake region has reached the sleepers beyond it."""
    n = awake.shape[0]
    front = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        if awake[i] and change[i] > threshold:
            for k in range(indptr[i], indptr[i + 1]):
                j = indices[k]
                if not awake[j]:
                    front[j] = True
    woke = 0
    for _ in range(rings):
        grew = np.zeros(n, dtype=np.bool_)
        any_new = False
        for i in range(n):
            if front[i] and not awake[i]:
                awake[i] = True
                woke += 1
                any_new = True
                for k in range(indptr[i], indptr[i + 1]):
                    j = indices[k]
                    if not awake[j]:
                        grew[j] = True
        if not any_new:
            break
        front = grew
    return woke

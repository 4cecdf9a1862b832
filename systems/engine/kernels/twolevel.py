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


@njit(cache=True)
def local_forces(x, tets, D, elems, w_arap, w_vol, quats, max_rot, rot_tol, rhs):
    """The projective local step (chainsim.engine.kernels.projective.local_step, same energy and
    right-hand side) over the listed elements only, `elems` (an index array, so a sleeping body's
    frame costs its awake elements, not the whole element list), with every per-element quantity in
    registers, and the rotation refined at most `max_rot` times, stopping once a refinement would turn
    it by less than `rot_tol` radians (warm-started rotations of slowly moving elements stop after one
    test). rhs (N, 3) is overwritten."""
    rhs[:] = 0.0
    for k in range(elems.shape[0]):
        t = elems[k]
        i0 = tets[t, 0]
        i1 = tets[t, 1]
        i2 = tets[t, 2]
        i3 = tets[t, 3]
        a10 = D[t, 1, 0]
        a11 = D[t, 1, 1]
        a12 = D[t, 1, 2]
        a20 = D[t, 2, 0]
        a21 = D[t, 2, 1]
        a22 = D[t, 2, 2]
        a30 = D[t, 3, 0]
        a31 = D[t, 3, 1]
        a32 = D[t, 3, 2]
        e1 = x[i1, 0] - x[i0, 0]
        e2 = x[i2, 0] - x[i0, 0]
        e3 = x[i3, 0] - x[i0, 0]
        f00 = e1 * a10 + e2 * a20 + e3 * a30
        f01 = e1 * a11 + e2 * a21 + e3 * a31
        f02 = e1 * a12 + e2 * a22 + e3 * a32
        e1 = x[i1, 1] - x[i0, 1]
        e2 = x[i2, 1] - x[i0, 1]
        e3 = x[i3, 1] - x[i0, 1]
        f10 = e1 * a10 + e2 * a20 + e3 * a30
        f11 = e1 * a11 + e2 * a21 + e3 * a31
        f12 = e1 * a12 + e2 * a22 + e3 * a32
        e1 = x[i1, 2] - x[i0, 2]
        e2 = x[i2, 2] - x[i0, 2]
        e3 = x[i3, 2] - x[i0, 2]
        f20 = e1 * a10 + e2 * a20 + e3 * a30
        f21 = e1 * a11 + e2 * a21 + e3 * a31
        f22 = e1 * a12 + e2 * a22 + e3 * a32
        w = quats[t, 0]
        qx = quats[t, 1]
        qy = quats[t, 2]
        qz = quats[t, 3]
        for it in range(max_rot + 1):
            r00 = 1 - 2 * (qy * qy + qz * qz)
            r01 = 2 * (qx * qy - w * qz)
            r02 = 2 * (qx * qz + w * qy)
            r10 = 2 * (qx * qy + w * qz)
            r11 = 1 - 2 * (qx * qx + qz * qz)
            r12 = 2 * (qy * qz - w * qx)
            r20 = 2 * (qx * qz - w * qy)
            r21 = 2 * (qy * qz + w * qx)
            r22 = 1 - 2 * (qx * qx + qy * qy)
            if it == max_rot:  # R is the rotation of the last quaternion
                break
            ox = (r10 * f20 - r20 * f10) + (r11 * f21 - r21 * f11) + (r12 * f22 - r22 * f12)
            oy = (r20 * f00 - r00 * f20) + (r21 * f01 - r01 * f21) + (r22 * f02 - r02 * f22)
            oz = (r00 * f10 - r10 * f00) + (r01 * f11 - r11 * f01) + (r02 * f12 - r12 * f02)
            dot = (
                r00 * f00
                + r10 * f10
                + r20 * f20
                + r01 * f01
                + r11 * f11
                + r21 * f21
                + r02 * f02
                + r12 * f12
                + r22 * f22
            )
            s = 1.0 / (abs(dot) + 1e-9)
            ox *= s
            oy *= s
            oz *= s
            a2 = ox * ox + oy * oy + oz * oz
            if a2 < max(rot_tol, 1e-13) ** 2:  # below 1e-13: round-off, R is the exact polar rotation
                break
            angle = np.sqrt(a2)
            ha = 0.5 * angle
            if ha < 0.05:
                h2 = ha * ha
                sn = 0.5 * (1.0 - h2 / 6.0 + h2 * h2 / 120.0)
                cs = 1.0 - 0.5 * h2 + h2 * h2 / 24.0
            else:
                sn = np.sin(ha) / angle
                cs = np.cos(ha)
            dx = ox * sn
            dy = oy * sn
            dz = oz * sn
            nw = cs * w - dx * qx - dy * qy - dz * qz
            nx = cs * qx + dx * w + dy * qz - dz * qy
            ny = cs * qy - dx * qz + dy * w + dz * qx
            nz = cs * qz + dx * qy - dy * qx + dz * w
            nq = 1.0 / np.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
            w = nw * nq
            qx = nx * nq
            qy = ny * nq
            qz = nz * nq
        quats[t, 0] = w
        quats[t, 1] = qx
        quats[t, 2] = qy
        quats[t, 3] = qz
        trs = r00 * f00 + r10 * f10 + r20 * f20 + r01 * f01 + r11 * f11 + r21 * f21 + r02 * f02 + r12 * f12 + r22 * f22
        wv = w_vol[t]
        wr = w_arap[t] - wv * (trs - 3.0) / 3.0
        m00 = wr * r00 + wv * f00
        m01 = wr * r01 + wv * f01
        m02 = wr * r02 + wv * f02
        m10 = wr * r10 + wv * f10
        m11 = wr * r11 + wv * f11
        m12 = wr * r12 + wv * f12
        m20 = wr * r20 + wv * f20
        m21 = wr * r21 + wv * f21
        m22 = wr * r22 + wv * f22
        g1 = m00 * a10 + m01 * a11 + m02 * a12
        g2 = m00 * a20 + m01 * a21 + m02 * a22
        g3 = m00 * a30 + m01 * a31 + m02 * a32
        rhs[i1, 0] += g1
        rhs[i2, 0] += g2
        rhs[i3, 0] += g3
        rhs[i0, 0] -= g1 + g2 + g3
        g1 = m10 * a10 + m11 * a11 + m12 * a12
        g2 = m10 * a20 + m11 * a21 + m12 * a22
        g3 = m10 * a30 + m11 * a31 + m12 * a32
        rhs[i1, 1] += g1
        rhs[i2, 1] += g2
        rhs[i3, 1] += g3
        rhs[i0, 1] -= g1 + g2 + g3
        g1 = m20 * a10 + m21 * a11 + m22 * a12
        g2 = m20 * a20 + m21 * a21 + m22 * a22
        g3 = m20 * a30 + m21 * a31 + m22 * a32
        rhs[i1, 2] += g1
        rhs[i2, 2] += g2
        rhs[i3, 2] += g3
        rhs[i0, 2] -= g1 + g2 + g3
    return rhs

"""Projective dynamics local step (numba): per-tetrahedron rotations and volume targets, scattered.

For each live tetrahedron, F = X D (X the 3x4 corner positions, D the 4x3 rest operator). The
as-rigid-as-possible target is F's rotation R, found by Mueller et al.'s iterative extraction
(quaternion updates, warm-started from the last frame's rotation, so one or two iterations suffice
between frames); the volume target P = F - (tr(R^T F) - 3) / 3 R shifts F's singular values equally
until they sum to 3, the closest point of that set, so the two projections are those of corotational
linear elasticity, mu |F - R|^2 + lambda / 2 (tr(R^T F) - 3)^2 per unit volume. The right-hand side
gathers D (w_a R + w_v P)^T per tetrahedron into its four corners.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(cache=True)
def _quat_to_mat(q, R):
    w, x, y, z = q[0], q[1], q[2], q[3]
    R[0, 0] = 1 - 2 * (y * y + z * z)
    R[0, 1] = 2 * (x * y - w * z)
    R[0, 2] = 2 * (x * z + w * y)
    R[1, 0] = 2 * (x * y + w * z)
    R[1, 1] = 1 - 2 * (x * x + z * z)
    R[1, 2] = 2 * (y * z - w * x)
    R[2, 0] = 2 * (x * z - w * y)
    R[2, 1] = 2 * (y * z + w * x)
    R[2, 2] = 1 - 2 * (x * x + y * y)


@njit(cache=True)
def extract_rotation(A, q, iterations):
    """Rotation of A (3x3) by Mueller et al. 2016, refining unit quaternion q (w, x, y, z) in place."""
    R = np.zeros((3, 3))
    return rotation_into(A, q, iterations, R)


@njit(cache=True)
def rotation_into(A, q, iterations, R):
    """extract_rotation writing into the caller's R (no allocation: it runs once per tetrahedron)."""
    for _ in range(iterations):
        _quat_to_mat(q, R)
        # omega = sum_i r_i x a_i / (|sum_i r_i . a_i| + eps)
        ox = oy = oz = 0.0
        dot = 0.0
        for i in range(3):
            rx, ry, rz = R[0, i], R[1, i], R[2, i]
            ax, ay, az = A[0, i], A[1, i], A[2, i]
            ox += ry * az - rz * ay
            oy += rz * ax - rx * az
            oz += rx * ay - ry * ax
            dot += rx * ax + ry * ay + rz * az
        s = 1.0 / (abs(dot) + 1e-9)
        ox *= s
        oy *= s
        oz *= s
        angle = np.sqrt(ox * ox + oy * oy + oz * oz)
        if angle < 1e-13:  # round-off: the forces use R as the exact polar rotation
            break
        ha = 0.5 * angle
        if ha < 0.05:
            # warm-started rotations change little per step: Taylor terms to 1e-12, no sin or cos
            h2 = ha * ha
            sn = 0.5 * (1.0 - h2 / 6.0 + h2 * h2 / 120.0)
            cs = 1.0 - 0.5 * h2 + h2 * h2 / 24.0
        else:
            sn = np.sin(ha) / angle
            cs = np.cos(ha)
        dw, dx, dy, dz = cs, ox * sn, oy * sn, oz * sn
        w, x, y, z = q[0], q[1], q[2], q[3]
        q[0] = dw * w - dx * x - dy * y - dz * z
        q[1] = dw * x + dx * w + dy * z - dz * y
        q[2] = dw * y - dx * z + dy * w + dz * x
        q[3] = dw * z + dx * y - dy * x + dz * w
        nq = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
        for k in range(4):
            q[k] /= nq
    _quat_to_mat(q, R)
    return R


@njit(cache=True)
def local_step(x, tets, D, active, w_arap, w_vol, quats, rot_iterations, rhs):
    """Project every live tet and accumulate the elastic right-hand side (rhs (N,3), overwritten).

    D (T, 4, 3) must be a tetrahedron's rest operator: rows 1..3 Dm^-1, row 0 minus their sum."""
    rhs[:] = 0.0
    F = np.zeros((3, 3))
    R = np.zeros((3, 3))
    M = np.zeros((3, 3))
    for t in range(tets.shape[0]):
        if not active[t]:
            continue
        # a tetrahedron's D has rows Dm^-1 (corners 1..3) and minus their sum (corner 0), so F is built
        # from the three edges from corner 0 and corner 0 gets minus the others' share: 27 products
        # instead of 36 each way
        i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
        for r in range(3):
            e1 = x[i1, r] - x[i0, r]
            e2 = x[i2, r] - x[i0, r]
            e3 = x[i3, r] - x[i0, r]
            for col in range(3):
                F[r, col] = e1 * D[t, 1, col] + e2 * D[t, 2, col] + e3 * D[t, 3, col]
        rotation_into(F, quats[t], rot_iterations, R)
        # volume target P = F - c R with c = (tr(R^T F) - 3) / 3: the closest point to F on the set whose
        # signed singular values sum to 3 (a uniform shift of F's singular values), so w_v / 2 |F - P|^2 is
        # (lambda V / 2) (tr(R^T F) - 3)^2 and its gradient w_v (F - P) = lambda V (tr(R^T F) - 3) R;
        # R is a proper rotation, so an inverted element is pushed back out, never towards a reflection
        trs = 0.0
        for r in range(3):
            for c in range(3):
                trs += R[r, c] * F[r, c]
        wr = w_arap[t] - w_vol[t] * (trs - 3.0) / 3.0
        for r in range(3):
            for c in range(3):
                M[r, c] = wr * R[r, c] + w_vol[t] * F[r, c]
        for r in range(3):
            g1 = M[r, 0] * D[t, 1, 0] + M[r, 1] * D[t, 1, 1] + M[r, 2] * D[t, 1, 2]
            g2 = M[r, 0] * D[t, 2, 0] + M[r, 1] * D[t, 2, 1] + M[r, 2] * D[t, 2, 2]
            g3 = M[r, 0] * D[t, 3, 0] + M[r, 1] * D[t, 3, 1] + M[r, 2] * D[t, 3, 2]
            rhs[i1, r] += g1
            rhs[i2, r] += g2
            rhs[i3, r] += g3
            rhs[i0, r] -= g1 + g2 + g3
    return rhs


@njit(cache=True)
def local_step_tri(x, tris, D, active, w_arap, rhs):
    """Membrane triangles: project F (3x2) onto its nearest orthonormal-column matrix R = F (F^T F)^-1/2
    and accumulate D (w R)^T into the corners (rhs (N,3), overwritten)."""
    rhs[:] = 0.0
    F = np.zeros((3, 2))
    R = np.zeros((3, 2))
    for t in range(tris.shape[0]):
        if not active[t]:
            continue
        for r in range(3):
            for c in range(2):
                acc = 0.0
                for k in range(3):
                    acc += x[tris[t, k], r] * D[t, k, c]
                F[r, c] = acc
        a = F[0, 0] * F[0, 0] + F[1, 0] * F[1, 0] + F[2, 0] * F[2, 0]
        b = F[0, 0] * F[0, 1] + F[1, 0] * F[1, 1] + F[2, 0] * F[2, 1]
        d = F[0, 1] * F[0, 1] + F[1, 1] * F[1, 1] + F[2, 1] * F[2, 1]
        det = a * d - b * b
        if det <= 1e-30:
            continue  # a collapsed triangle has no direction to restore: it contributes nothing
        s = np.sqrt(det)
        tau = np.sqrt(a + d + 2.0 * s)
        # sqrt(C) = (C + s I) / tau for 2x2 SPD C; its inverse by the 2x2 formula
        m00, m01, m11 = (a + s) / tau, b / tau, (d + s) / tau
        idet = 1.0 / (m00 * m11 - m01 * m01)
        i00, i01, i11 = m11 * idet, -m01 * idet, m00 * idet
        for r in range(3):
            R[r, 0] = F[r, 0] * i00 + F[r, 1] * i01
            R[r, 1] = F[r, 0] * i01 + F[r, 1] * i11
        for k in range(3):
            i = tris[t, k]
            for r in range(3):
                rhs[i, r] += w_arap[t] * (D[t, k, 0] * R[r, 0] + D[t, k, 1] * R[r, 1])
    return rhs


@njit(cache=True, parallel=True)
def spmv3(indptr, indices, data, x, out):
    """out = A x for a CSR matrix A and three right-hand sides at once (x, out (n, 3)); rows apart in
    numba's threads (each row's sum in the same order whatever their number)."""
    for i in prange(indptr.shape[0] - 1):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            v = data[k]
            a0 += v * x[j, 0]
            a1 += v * x[j, 1]
            a2 += v * x[j, 2]
        out[i, 0] = a0
        out[i, 1] = a1
        out[i, 2] = a2


@njit(cache=True)
def pcg3(indptr, indices, data, inv_diag, b, x, iterations, tolerance, r, z, p, q):
    """Jacobi-preconditioned conjugate gradients on A x = b (A symmetric positive definite, CSR), one
    independent solve per column of b (n, 3), warm-started from x and updated in place; at most
    `iterations` steps, stopping early when every column's residual is below tolerance * |b| (a
    column that gets there stops changing). r, z, p, q are (n, 3) scratch arrays. Returns the steps
    taken. The three columns share every pass over the arrays (one pass per vector operation).
    """
    n = b.shape[0]
    spmv3(indptr, indices, data, x, q)
    rz = np.zeros(3)
    rr = np.zeros(3)
    bb = np.zeros(3)
    pq = np.zeros(3)
    alpha = np.zeros(3)
    beta = np.zeros(3)
    live = np.zeros(3, dtype=np.bool_)
    for i in range(n):
        for c in range(3):
            r[i, c] = b[i, c] - q[i, c]
            z[i, c] = inv_diag[i] * r[i, c]
            p[i, c] = z[i, c]
            rz[c] += r[i, c] * z[i, c]
            rr[c] += r[i, c] * r[i, c]
            bb[c] += b[i, c] * b[i, c]
    done = 0
    for _ in range(iterations):
        any_live = False
        for c in range(3):
            live[c] = rr[c] > tolerance * tolerance * max(bb[c], 1e-300) and rz[c] > 0.0
            any_live = any_live or live[c]
        if not any_live:
            break
        done += 1
        spmv3(indptr, indices, data, p, q)
        pq[:] = 0.0
        for i in range(n):
            for c in range(3):
                pq[c] += p[i, c] * q[i, c]
        for c in range(3):
            alpha[c] = rz[c] / pq[c] if live[c] and pq[c] > 0.0 else 0.0
            if alpha[c] == 0.0:
                live[c] = False
        rz_new = np.zeros(3)
        rr[:] = 0.0
        for i in range(n):
            for c in range(3):
                if live[c]:
                    x[i, c] += alpha[c] * p[i, c]
                    r[i, c] -= alpha[c] * q[i, c]
                    z[i, c] = inv_diag[i] * r[i, c]
                    rz_new[c] += r[i, c] * z[i, c]
                rr[c] += r[i, c] * r[i, c]
        for c in range(3):
            beta[c] = rz_new[c] / rz[c] if live[c] else 0.0
            if live[c]:
                rz[c] = rz_new[c]
            else:
                rz[c] = 0.0  # a finished column stays finished
        for i in range(n):
            for c in range(3):
                if live[c]:
                    p[i, c] = z[i, c] + beta[c] * p[i, c]
    return done

"""Kernels of the two-level tissue solve (chainsim.systems.engine.bodies.hybrid): the trilinear map from a coarse
grid to the nodes of a tetrahedral mesh, the rest stiffness of linear elasticity per tetrahedron, the
front that wakes sleeping nodes when a disturbance reaches them, and the assembly of the sparse
matrices over a set of tetrahedra (their pattern, their values, and the pieces they join).

All are pure functions on arrays; the body wraps their output in scipy sparse matrices.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


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
    projective body's rest operator), mu and lam (T,) each element's Lame parameters (a layered body has
    several). At rest this is the Hessian of the corotational energy, whose rotation term vanishes to
    first order."""
    T = D.shape[0]
    K = np.zeros((T, 12, 12))
    for t in range(T):
        v = vol[t]
        mu_t, lam_t = mu[t], lam[t]
        for a in range(4):
            for b in range(4):
                gg = D[t, a, 0] * D[t, b, 0] + D[t, a, 1] * D[t, b, 1] + D[t, a, 2] * D[t, b, 2]
                for i in range(3):
                    for j in range(3):
                        k = lam_t * D[t, a, i] * D[t, b, j] + mu_t * D[t, a, j] * D[t, b, i]
                        if i == j:
                            k += mu_t * gg
                        K[t, 3 * a + i, 3 * b + j] = v * k
    return K


@njit(cache=True, parallel=True)
def follow_far(cids, cw, Y, rest, x, anchor, far_u, sleeping, moved):
    """Place the sleepers on a far field given on a coarse grid (chainsim.systems.engine.bodies.far_field).
    For every node, u = sum_k cw[i, k] Y[cids[i, k]] (rows of cw all zero for nodes the field leaves
    alone); its anchor moves by the change of u since far_u, which becomes u; a node in `sleeping` goes
    to rest + u, and `moved` gets that move (zero elsewhere). Returns the largest move of a coordinate.
    One pass over the nodes, apart in numba's threads; the result does not depend on their number."""
    n = x.shape[0]
    big = np.zeros(n)
    for i in prange(n):
        for a in range(3):
            u = 0.0
            for k in range(8):
                u += cw[i, k] * Y[cids[i, k], a]
            anchor[i, a] += u - far_u[i, a]
            far_u[i, a] = u
            d = 0.0
            if sleeping[i]:
                d = rest[i, a] + u - x[i, a]
                x[i, a] += d
            moved[i, a] = d
            big[i] = max(big[i], abs(d))
    top = 0.0
    for i in range(n):
        top = max(top, big[i])
    return top


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


# no fast-math here: local_forces calls this kernel, and with reassociation allowed the code compiled with
# its caller in one process rounded differently from the code loaded from numba's cache, so a replay
# process missed the simulator's digest (tests/kernels/test_cached_kernels_same_bits.py); 10 % slower
@njit(cache=True, parallel=True)
def refine_rotations(F, Q, iterations):
    """Refine unit quaternions Q (M, 4) (w, x, y, z) towards the rotations of the matrices F (M, 9),
    row-major, `iterations` times, all elements per pass, with no branch and no trigonometry, so the
    loop runs in SIMD lanes. Each pass is Mueller et al.'s update (the torque omega = sum_i r_i x f_i /
    |sum_i r_i . f_i| of the current rotation's columns against F's), applied as the first-order
    quaternion step q + (0, omega / 2) q, normalised: the same fixed point (omega = 0 exactly at F's polar
    rotation) and, for the small corrections of a warm start, the same step to second order."""
    m = F.shape[0]
    for _ in range(iterations):
        for t in prange(m):  # elements apart, in the threads numba has (SIMD lanes within each)
            w = Q[t, 0]
            qx = Q[t, 1]
            qy = Q[t, 2]
            qz = Q[t, 3]
            r00 = 1 - 2 * (qy * qy + qz * qz)
            r01 = 2 * (qx * qy - w * qz)
            r02 = 2 * (qx * qz + w * qy)
            r10 = 2 * (qx * qy + w * qz)
            r11 = 1 - 2 * (qx * qx + qz * qz)
            r12 = 2 * (qy * qz - w * qx)
            r20 = 2 * (qx * qz - w * qy)
            r21 = 2 * (qy * qz + w * qx)
            r22 = 1 - 2 * (qx * qx + qy * qy)
            f00, f01, f02 = F[t, 0], F[t, 1], F[t, 2]
            f10, f11, f12 = F[t, 3], F[t, 4], F[t, 5]
            f20, f21, f22 = F[t, 6], F[t, 7], F[t, 8]
            ox = (r10 * f20 - r20 * f10) + (r11 * f21 - r21 * f11) + (r12 * f22 - r22 * f12)
            oy = (r20 * f00 - r00 * f20) + (r21 * f01 - r01 * f21) + (r22 * f02 - r02 * f22)
            oz = (r00 * f10 - r10 * f00) + (r01 * f11 - r11 * f01) + (r02 * f12 - r12 * f02)
            dot = r00 * f00 + r10 * f10 + r20 * f20 + r01 * f01 + r11 * f11 + r21 * f21 + r02 * f02 + r12 * f12
            dot += r22 * f22
            s = 0.5 / (abs(dot) + 1e-9)
            dx = ox * s
            dy = oy * s
            dz = oz * s
            nw = w - dx * qx - dy * qy - dz * qz
            nx = qx + dx * w + dy * qz - dz * qy
            ny = qy - dx * qz + dy * w + dz * qx
            nz = qz + dx * qy - dy * qx + dz * w
            nq = 1.0 / np.sqrt(nw * nw + nx * nx + ny * ny + nz * nz)
            Q[t, 0] = nw * nq
            Q[t, 1] = nx * nq
            Q[t, 2] = ny * nq
            Q[t, 3] = nz * nq


@njit(cache=True, inline="always")
def volume_barrier(J, kappa, j_barrier):
    """The compression barrier psi(J) = kappa (j_b - J)^2 / J below j_b (zero above, with zero slope
    there, so the energy stays C1), and -psi'(J), the push outwards per unit of dJ. kappa is the bulk
    modulus times the rest volume. The corotational energy alone charges a squeezed element through the
    sum of its stretches, not its volume, so a far shear could fold elements flat at little cost; the
    barrier makes that cost grow without bound, as the neo-Hookean energy's -ln J does. Below J = 0.01
    it continues along its tangent, finite for an element that is already inverted, which it pushes out."""
    if J >= j_barrier:
        return 0.0, 0.0
    jc = max(J, 0.01)
    d = j_barrier - jc
    slope = -kappa * d * (j_barrier + jc) / (jc * jc)  # psi'(jc)
    return kappa * d * d / jc + slope * (J - jc), -slope


@njit(cache=True, parallel=True)
def gradients(x, tets, D, elems):
    """The deformation gradients (m, 9), row-major, of the listed tetrahedra at positions x: F = X D."""
    m = elems.shape[0]
    Fs = np.empty((m, 9))
    for k in prange(m):
        t = elems[k]
        i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
        for r in range(3):
            e1 = x[i1, r] - x[i0, r]
            e2 = x[i2, r] - x[i0, r]
            e3 = x[i3, r] - x[i0, r]
            for c in range(3):
                Fs[k, 3 * r + c] = e1 * D[t, 1, c] + e2 * D[t, 2, c] + e3 * D[t, 3, c]
    return Fs


@njit(cache=True, inline="always")
def det9(F):
    """det of a 3 x 3 matrix given as its 9 entries, row-major."""
    return F[0] * (F[4] * F[8] - F[5] * F[7]) - F[1] * (F[3] * F[8] - F[5] * F[6]) + F[2] * (F[3] * F[7] - F[4] * F[6])


@njit(cache=True, inline="always")
def element_forces(F, q, Dt, w_a, w_v, j_barrier, G):
    """One element's share of the local step: its corner forces G (3 axes x corners 1..3; corner 0 takes
    minus their sum) for deformation gradient F (9, row-major), rotation q and shape gradients Dt (4, 3);
    returns its energy and det F."""
    w, qx, qy, qz = q[0], q[1], q[2], q[3]
    # R's rows as scalars: an array here would be a heap allocation per element in the threads' loop
    r0, r1, r2 = 1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - w * qz), 2 * (qx * qz + w * qy)
    r3, r4, r5 = 2 * (qx * qy + w * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - w * qx)
    r6, r7, r8 = 2 * (qx * qz - w * qy), 2 * (qy * qz + w * qx), 1 - 2 * (qx * qx + qy * qy)
    trs = r0 * F[0] + r1 * F[1] + r2 * F[2] + r3 * F[3] + r4 * F[4] + r5 * F[5] + r6 * F[6] + r7 * F[7] + r8 * F[8]
    ff = 0.0
    for c in range(9):
        ff += F[c] * F[c]
    # w_a = 2 mu V and w_v = 3 lambda V: |F - R|^2 = |F|^2 - 2 tr(R^T F) + 3
    energy = 0.5 * w_a * (ff - 2.0 * trs + 3.0) + w_v / 6.0 * (trs - 3.0) * (trs - 3.0)
    J = det9(F)
    e_b, push = volume_barrier(J, (w_a + w_v) / 3.0, j_barrier)
    # volume target as in projective.local_step: M = w_a R + w_v (F - (tr(R^T F) - 3) / 3 R)
    wr = w_a - w_v * (trs - 3.0) / 3.0
    for r in range(3):
        if r == 0:
            a0, a1, a2 = r0, r1, r2
        elif r == 1:
            a0, a1, a2 = r3, r4, r5
        else:
            a0, a1, a2 = r6, r7, r8
        # the barrier's force: -psi'(J) dJ/dF, and dJ/dF is F's cofactor matrix (row r: the cross
        # product of F's other two rows)
        ra, rb = 3 * ((r + 1) % 3), 3 * ((r + 2) % 3)
        m0 = wr * a0 + w_v * F[3 * r] + push * (F[ra + 1] * F[rb + 2] - F[ra + 2] * F[rb + 1])
        m1 = wr * a1 + w_v * F[3 * r + 1] + push * (F[ra + 2] * F[rb] - F[ra] * F[rb + 2])
        m2 = wr * a2 + w_v * F[3 * r + 2] + push * (F[ra] * F[rb + 1] - F[ra + 1] * F[rb])
        for j in range(3):
            G[r, j] = m0 * Dt[j + 1, 0] + m1 * Dt[j + 1, 1] + m2 * Dt[j + 1, 2]
    return energy + e_b, J


@njit(cache=True, parallel=True)
def local_forces(x, tets, D, elems, w_arap, w_vol, quats, rot_iterations, rhs, j_barrier):
    """The projective local step (chainsim.systems.engine.kernels.projective.local_step: the same energy and
    right-hand side) over the listed elements only, `elems` (an index array, so a sleeping body's frame
    costs its awake elements, not the whole element list), in four passes: every element's F, then
    `rot_iterations` refinements of every rotation at once (refine_rotations), then each element's three
    corner forces, then their scatter into rhs (N, 3, overwritten). The first three take the elements
    apart in numba's threads; the scatter, where elements share nodes, runs in order, so the sums are the
    same whatever the thread count. quats (T, 4) are read and written for the listed elements.

    Returns (energy, min_j): the listed elements' energy sum mu V |F - R|^2 + lambda V / 2 (tr(R^T F) - 3)^2
    at the refined rotations (an upper bound of the energy at the exact polar rotations, equal to it once
    they have converged), and the smallest det F among them. The solver's line search reads both: the
    energy must fall, and no element may be turned inside out (det F <= 0), which this energy, unlike the
    neo-Hookean one, does not forbid by itself."""
    m = elems.shape[0]
    Fs = gradients(x, tets, D, elems)
    Q = np.empty((m, 4))
    En = np.empty(m)
    Js = np.empty(m)
    for k in prange(m):
        for c in range(4):
            Q[k, c] = quats[elems[k], c]
    refine_rotations(Fs, Q, rot_iterations)
    G = np.empty((m, 3, 3))  # per element, per axis r: the forces on corners 1, 2, 3 (corner 0 takes minus their sum)
    for k in prange(m):
        t = elems[k]
        for c in range(4):
            quats[t, c] = Q[k, c]
        En[k], Js[k] = element_forces(Fs[k], Q[k], D[t], w_arap[t], w_vol[t], j_barrier, G[k])
    rhs[:] = 0.0
    for k in range(m):
        t = elems[k]
        i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
        for r in range(3):
            g1, g2, g3 = G[k, r, 0], G[k, r, 1], G[k, r, 2]
            rhs[i1, r] += g1
            rhs[i2, r] += g2
            rhs[i3, r] += g3
            rhs[i0, r] -= g1 + g2 + g3
    energy = 0.0
    min_j = np.inf
    for k in range(m):  # in order: the same sum whatever the thread count
        energy += En[k]
        min_j = min(min_j, Js[k])
    return energy, min_j


@njit(cache=True)
def ring_max(indptr, indices, nodes, values, passes):
    """values (N,) with each of `nodes` raised to the largest value within `passes` rings of it among
    `nodes` (graph CSR indptr/indices); the others unchanged. Returns a new array."""
    n = values.shape[0]
    inside = np.zeros(n, dtype=np.bool_)
    for i in nodes:
        inside[i] = True
    cur = values.copy()
    for _ in range(passes):
        nxt = cur.copy()
        for i in nodes:
            best = cur[i]
            for k in range(indptr[i], indptr[i + 1]):
                j = indices[k]
                if inside[j] and cur[j] > best:
                    best = cur[j]
            nxt[i] = best
        cur = nxt
    return cur


@njit(cache=True, parallel=True)
def min_det(x, tets, D, elems):
    """The smallest det F (volume ratio) among the listed tetrahedra at positions x: the start of a
    frame checks a move of the grabbed nodes with it before any rotation is fitted."""
    m = elems.shape[0]
    Fs = gradients(x, tets, D, elems)
    Js = np.empty(m)
    for k in prange(m):
        Js[k] = det9(Fs[k])
    out = np.inf
    for k in range(m):
        out = min(out, Js[k])
    return out


@njit(cache=True)
def det_at(x, tets, D, t):
    """det F of tetrahedron t at positions x, in one thread: the products and sums of `gradients` and
    `det9` in their order, so the very ratio min_det finds for it (tests/kernels compare the bits)."""
    i0, i1, i2, i3 = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
    F = np.empty(9)
    for r in range(3):
        e1 = x[i1, r] - x[i0, r]
        e2 = x[i2, r] - x[i0, r]
        e3 = x[i3, r] - x[i0, r]
        for c in range(3):
            F[3 * r + c] = e1 * D[t, 1, c] + e2 * D[t, 2, c] + e3 * D[t, 3, c]
    return det9(F)


@njit(cache=True, parallel=True)
def min_det_below(x, tets, D, elems, floor):
    """min_det (the same ratios, taken in the same order, so the same number) and the position in
    `elems` of the first tetrahedron whose ratio is below `floor`, -1 when none is: a caller that
    retries a move can try that one first next time."""
    m = elems.shape[0]
    Fs = gradients(x, tets, D, elems)
    Js = np.empty(m)
    for k in prange(m):
        Js[k] = det9(Fs[k])
    out = np.inf
    below = -1
    for k in range(m):
        out = min(out, Js[k])
        if below < 0 and Js[k] < floor:
            below = k
    return out, below


@njit(cache=True)
def tet_pattern(n, tets, elems):
    """The sparsity pattern of a matrix over nodes assembled from tetrahedra `elems`: CSR (indptr,
    indices) with row a holding every node that shares one of those tetrahedra with a (a included),
    sorted. Rows are gathered per node and sorted one by one (each a few dozen entries), so the cost
    is linear in the tetrahedra rather than a sort of all their 16 pairs."""
    start = np.zeros(n + 1, dtype=np.int64)
    for e in elems:
        for k in range(4):
            start[tets[e, k] + 1] += 4
    for a in range(n):
        start[a + 1] += start[a]
    buf = np.empty(start[n], dtype=np.int64)
    fill = start[:n].copy()
    for e in elems:
        for k in range(4):
            a = tets[e, k]
            for m in range(4):
                buf[fill[a]] = tets[e, m]
                fill[a] += 1
    indptr = np.zeros(n + 1, dtype=np.int64)
    out = np.empty(start[n], dtype=np.int64)
    m = 0
    for a in range(n):
        row = np.sort(buf[start[a] : start[a + 1]])
        last = -1
        for v in row:
            if v != last:
                out[m] = v
                m += 1
                last = v
        indptr[a + 1] = m
    return indptr, out[:m].copy()


@njit(cache=True)
def assemble_tets(indptr, indices, tets, elems, D, w, K_e):
    """Projective dynamics' global matrix (sum over elements of w D D^T, one value per node pair) and
    the rest stiffness (3 x 3 per node pair, from K_e's 12 x 12 element matrices, dof 3 k + axis) of
    tetrahedra `elems`, into the pattern of tet_pattern: data arrays (nnz,) and (nnz, 3, 3)."""
    nnz = indices.shape[0]
    L = np.zeros(nnz)
    K = np.zeros((nnz, 3, 3))
    for e in elems:
        for k in range(4):
            a = tets[e, k]
            lo, hi = indptr[a], indptr[a + 1]
            for m in range(4):
                b = tets[e, m]
                p = lo + np.searchsorted(indices[lo:hi], b)
                s = 0.0
                for c in range(D.shape[2]):
                    s += D[e, k, c] * D[e, m, c]
                L[p] += w[e] * s
                for i in range(3):
                    for j in range(3):
                        K[p, i, j] += K_e[e, 3 * k + i, 3 * m + j]
    return L, K


@njit(cache=True)
def tet_components(n, tets, active):
    """For each node, a representative of its piece: nodes joined through live tetrahedra share one
    (union-find with path halving); a node in no live tetrahedron is its own piece."""
    parent = np.arange(n)
    for e in range(tets.shape[0]):
        if not active[e]:
            continue
        for k in range(1, 4):
            a, b = tets[e, 0], tets[e, k]
            while parent[a] != a:
                parent[a] = parent[parent[a]]
                a = parent[a]
            while parent[b] != b:
                parent[b] = parent[parent[b]]
                b = parent[b]
            if a != b:
                parent[max(a, b)] = min(a, b)
    root = np.empty(n, dtype=np.int64)
    for i in range(n):
        a = i
        while parent[a] != a:
            a = parent[a]
        root[i] = a
    return root


@njit(cache=True, parallel=True)
def bspmv3(indptr, indices, blocks, x, out):
    """out = K x for a block-CSR matrix of 3 x 3 blocks (blocks (nnzb, 3, 3)) and x, out (n, 3); rows
    apart in numba's threads (each row's sum in the same order whatever their number)."""
    for i in prange(indptr.shape[0] - 1):
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for k in range(indptr[i], indptr[i + 1]):
            j = indices[k]
            x0, x1, x2 = x[j, 0], x[j, 1], x[j, 2]
            a0 += blocks[k, 0, 0] * x0 + blocks[k, 0, 1] * x1 + blocks[k, 0, 2] * x2
            a1 += blocks[k, 1, 0] * x0 + blocks[k, 1, 1] * x1 + blocks[k, 1, 2] * x2
            a2 += blocks[k, 2, 0] * x0 + blocks[k, 2, 1] * x1 + blocks[k, 2, 2] * x2
        out[i, 0] = a0
        out[i, 1] = a1
        out[i, 2] = a2


@njit(cache=True)
def _block_precondition(inv_blocks, r, z):
    """z = B^-1 r with B^-1 the inverses of the 3 x 3 diagonal blocks; returns r . z."""
    rz = 0.0
    for i in range(r.shape[0]):
        for a in range(3):
            z[i, a] = inv_blocks[i, a, 0] * r[i, 0] + inv_blocks[i, a, 1] * r[i, 1] + inv_blocks[i, a, 2] * r[i, 2]
            rz += r[i, a] * z[i, a]
    return rz


@njit(cache=True)
def block_pcg(indptr, indices, blocks, inv_blocks, b, x, iterations, r, z, p, q):
    """Conjugate gradients on K x = b (K symmetric positive definite, block CSR of 3 x 3 blocks: the rest
    stiffness of the solved nodes), preconditioned by the inverses of K's 3 x 3 diagonal blocks, from x = 0
    (x overwritten), at most `iterations` steps. Unlike projective dynamics' matrix, which carries the
    volume stiffness in every direction, K couples the axes as the volume term does, so the steps it
    gives a nearly incompressible body are not shrunk by the ratio lambda / mu. r, z, p, q: (n, 3)
    scratch. Returns the steps taken."""
    n = b.shape[0]
    # Element loops, not slice assignment: numba builds `r[:] = b`'s broadcast (and its error paths)
    # in seconds of compile, these in a fraction of one, with the same values.
    for i in range(n):
        for a in range(3):
            x[i, a] = 0.0
            r[i, a] = b[i, a]
    rz = _block_precondition(inv_blocks, r, z)
    for i in range(n):
        for a in range(3):
            p[i, a] = z[i, a]
    done = 0
    for _ in range(iterations):
        if not rz > 0.0:
            break
        bspmv3(indptr, indices, blocks, p, q)
        pq = 0.0
        for i in range(n):
            pq += p[i, 0] * q[i, 0] + p[i, 1] * q[i, 1] + p[i, 2] * q[i, 2]
        if not pq > 0.0:
            break
        alpha = rz / pq
        for i in range(n):
            for a in range(3):
                x[i, a] += alpha * p[i, a]
                r[i, a] -= alpha * q[i, a]
        rz_new = _block_precondition(inv_blocks, r, z)
        beta = rz_new / rz
        rz = rz_new
        for i in range(n):
            for a in range(3):
                p[i, a] = z[i, a] + beta * p[i, a]
        done += 1
    return done

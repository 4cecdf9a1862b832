"""XPBD constraint kernels (numba): corotational, stable Neo-Hookean and Green-strain tetrahedra, and
distance constraints.

The default tetrahedron is corotational: C_D = |F - R|_F (R the rotation of F) with compliance
1/(2 mu V) and C_H = det F - 1 with compliance 1/(lambda V); both vanish at rest, so a body at rest
stays there at any stiffness, element size and step. Macklin and Mueller's stable Neo-Hookean pair
(C_D = |F|_F, compliance 1/(mu V); C_H = det F - gamma, gamma = 1 + mu/l, compliance 1/(l V), the
caller passing l = lambda + mu after Smith et al.) is kept by name: it balances two constraints that
are not zero at rest, which holds only while the solve converges. Each constraint is projected with
the XPBD update dlambda = (-C - a~ lambda) / (sum w |grad C|^2 + a~), a~ = compliance / h^2. Distance
constraints (surface stretch and bending) use C = |xi - xj| - L. One Gauss-Seidel sweep per call, in
element order, so results do not depend on the thread count.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from chainsim.systems.engine.kernels.projective import rotation_into


@njit(cache=True)
def _apply(x, w, ids, g, dl):
    for k in range(4):
        i = ids[k]
        if w[i] > 0.0:
            x[i, 0] += w[i] * dl * g[k, 0]
            x[i, 1] += w[i] * dl * g[k, 1]
            x[i, 2] += w[i] * dl * g[k, 2]


@njit(cache=True)
def tet_sweep(x, w, tets, dm_inv, vol, active, mu, lam, gamma, h2, lam_d, lam_h):
    """One sweep over live tets: deviatoric then hydrostatic constraint of each (in place).

    x (N,3) positions, w (N,) inverse masses (0: pinned), tets (T,4), dm_inv (T,3,3), vol (T,),
    active (T,) bool, lam_d / lam_h (T,) accumulated multipliers of this step. Returns max |C_H|.
    The scratch matrices live outside the loop: an allocation per tetrahedron cost as much as its math.
    """
    g = np.zeros((4, 3))
    ids = np.zeros(4, dtype=np.int64)
    F = np.zeros((3, 3))
    P = np.zeros((3, 3))
    worst = 0.0
    for t in range(tets.shape[0]):
        if not active[t]:
            continue
        for k in range(4):
            ids[k] = tets[t, k]
        a, b, c, d = ids[0], ids[1], ids[2], ids[3]
        wsum_any = w[a] + w[b] + w[c] + w[d]
        if wsum_any == 0.0:
            continue
        # F = Ds Dm^-1, Ds columns x_b - x_a, x_c - x_a, x_d - x_a
        _deformation(x, tets, dm_inv, t, F)
        # -- deviatoric: C = |F|, dC/dF = F / |F|
        nf2 = 0.0
        for r in range(3):
            for col in range(3):
                nf2 += F[r, col] * F[r, col]
        nf = np.sqrt(nf2)
        if nf > 1e-12 and mu * vol[t] * h2 > 0.0:
            inv = 1.0 / nf
            for r in range(3):
                for col in range(3):
                    P[r, col] = F[r, col] * inv
            _grads(P, dm_inv[t], g)
            den = w[a] * _sq(g, 0) + w[b] * _sq(g, 1) + w[c] * _sq(g, 2) + w[d] * _sq(g, 3)
            alpha = 1.0 / (mu * vol[t] * h2)
            if den + alpha > 0.0:
                dl = (-nf - alpha * lam_d[t]) / (den + alpha)
                lam_d[t] += dl
                _apply(x, w, ids, g, dl)
                _deformation(x, tets, dm_inv, t, F)
        # -- hydrostatic: C = det F - gamma, dC/dF = cofactor(F)
        _cofactor(F, P)
        J = F[0, 0] * P[0, 0] + F[1, 0] * P[1, 0] + F[2, 0] * P[2, 0]
        _grads(P, dm_inv[t], g)
        den = w[a] * _sq(g, 0) + w[b] * _sq(g, 1) + w[c] * _sq(g, 2) + w[d] * _sq(g, 3)
        C = J - gamma
        kv = lam * vol[t] * h2
        if kv > 0.0:
            alpha = 1.0 / kv
            if den + alpha > 0.0:
                dl = (-C - alpha * lam_h[t]) / (den + alpha)
                lam_h[t] += dl
                _apply(x, w, ids, g, dl)
        if abs(J - 1.0) > worst:
            worst = abs(J - 1.0)
    return worst


@njit(cache=True)
def _sq(g, k):
    return g[k, 0] * g[k, 0] + g[k, 1] * g[k, 1] + g[k, 2] * g[k, 2]


@njit(cache=True)
def _grads(P, dmi, g):
    """Vertex gradients from dC/dF: columns of P Dm^-T for vertices 1..3, their negated sum for 0."""
    for k in range(3):
        for r in range(3):
            g[k + 1, r] = P[r, 0] * dmi[k, 0] + P[r, 1] * dmi[k, 1] + P[r, 2] * dmi[k, 2]
    for r in range(3):
        g[0, r] = -(g[1, r] + g[2, r] + g[3, r])


@njit(cache=True)
def distance_sweep(x, w, pairs, rest_len, compliance, active, h2, lam):
    """One sweep of distance constraints |xi - xj| = L with per-constraint compliance (in place)."""
    worst = 0.0
    for k in range(pairs.shape[0]):
        if not active[k]:
            continue
        i = pairs[k, 0]
        j = pairs[k, 1]
        wi = w[i]
        wj = w[j]
        if wi + wj == 0.0:
            continue
        d0 = x[i, 0] - x[j, 0]
        d1 = x[i, 1] - x[j, 1]
        d2 = x[i, 2] - x[j, 2]
        ln = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if ln < 1e-15:
            continue
        C = ln - rest_len[k]
        alpha = compliance[k] / h2
        dl = (-C - alpha * lam[k]) / (wi + wj + alpha)
        lam[k] += dl
        s = dl / ln
        x[i, 0] += wi * s * d0
        x[i, 1] += wi * s * d1
        x[i, 2] += wi * s * d2
        x[j, 0] -= wj * s * d0
        x[j, 1] -= wj * s * d1
        x[j, 2] -= wj * s * d2
        if abs(C) > worst * rest_len[k]:
            worst = abs(C) / max(rest_len[k], 1e-300)
    return worst


@njit(cache=True)
def tet_energy(x, tets, dm_inv, vol, active, mu, lam, gamma):
    """Elastic energy of the constraint form: sum V (mu/2 |F|^2 + lam/2 (J - gamma)^2) (for checks)."""
    e = 0.0
    for t in range(tets.shape[0]):
        if not active[t]:
            continue
        a, b, c, d = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
        F = np.zeros((3, 3))
        for r in range(3):
            e1 = x[b, r] - x[a, r]
            e2 = x[c, r] - x[a, r]
            e3 = x[d, r] - x[a, r]
            for col in range(3):
                F[r, col] = e1 * dm_inv[t, 0, col] + e2 * dm_inv[t, 1, col] + e3 * dm_inv[t, 2, col]
        J = np.linalg.det(F)
        e += vol[t] * (0.5 * mu * np.sum(F * F) + 0.5 * lam * (J - gamma) ** 2)
    return e


@njit(cache=True)
def _add_forces(out, tets, t, v, g):
    """Add -V (P Dm^-T) column k (g, from _grads) to vertex k of tet t."""
    for k in range(4):
        i = tets[t, k]
        out[i, 0] -= v * g[k, 0]
        out[i, 1] -= v * g[k, 1]
        out[i, 2] -= v * g[k, 2]


@njit(cache=True)
def _cofactor(F, out):
    """out = cofactor(F) = det(F) F^-T, the derivative of det F: columns f1 x f2, f2 x f0, f0 x f1."""
    for r in range(3):
        r1 = (r + 1) % 3
        r2 = (r + 2) % 3
        out[r, 0] = F[r1, 1] * F[r2, 2] - F[r2, 1] * F[r1, 2]
        out[r, 1] = F[r1, 2] * F[r2, 0] - F[r2, 2] * F[r1, 0]
        out[r, 2] = F[r1, 0] * F[r2, 1] - F[r2, 0] * F[r1, 1]


@njit(cache=True)
def _deformation(x, tets, dm_inv, t, F):
    a, b, c, d = tets[t, 0], tets[t, 1], tets[t, 2], tets[t, 3]
    for r in range(3):
        e1 = x[b, r] - x[a, r]
        e2 = x[c, r] - x[a, r]
        e3 = x[d, r] - x[a, r]
        for col in range(3):
            F[r, col] = e1 * dm_inv[t, 0, col] + e2 * dm_inv[t, 1, col] + e3 * dm_inv[t, 2, col]


@njit(cache=True)
def stvk_sweep(x, w, tets, dm_inv, vol, active, mu, lam, h2):
    """One sweep of Green-strain (StVK) constraints per live tet: E_ij = (f_i . f_j - delta_ij) / 2 for
    the 3 stretches (compliance 1/(2 mu V)) and 3 shears (1/(4 mu V)), then volume J - 1 (1/(lam V)).
    Every constraint is zero at rest, which keeps stiff, low-lambda materials stable. Returns max |J - 1|.
    """
    g = np.zeros((4, 3))
    ids = np.zeros(4, dtype=np.int64)
    F = np.zeros((3, 3))
    P = np.zeros((3, 3))
    worst = 0.0
    for t in range(tets.shape[0]):
        if not active[t]:
            continue
        for k in range(4):
            ids[k] = tets[t, k]
        if w[ids[0]] + w[ids[1]] + w[ids[2]] + w[ids[3]] == 0.0:
            continue
        for i in range(3):
            for j in range(i, 3):
                _deformation(x, tets, dm_inv, t, F)
                dot = F[0, i] * F[0, j] + F[1, i] * F[1, j] + F[2, i] * F[2, j]
                C = 0.5 * (dot - (1.0 if i == j else 0.0))
                P[:, :] = 0.0
                for r in range(3):
                    P[r, i] += 0.5 * F[r, j]
                    P[r, j] += 0.5 * F[r, i]
                _grads(P, dm_inv[t], g)
                den = w[ids[0]] * _sq(g, 0) + w[ids[1]] * _sq(g, 1) + w[ids[2]] * _sq(g, 2) + w[ids[3]] * _sq(g, 3)
                k = 2.0 * mu * vol[t] if i == j else 4.0 * mu * vol[t]
                if k * h2 <= 0.0:
                    continue
                alpha = 1.0 / (k * h2)
                if den + alpha > 0.0:
                    _apply(x, w, ids, g, -C / (den + alpha))
        _deformation(x, tets, dm_inv, t, F)
        J = (
            F[0, 0] * (F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1])
            - F[0, 1] * (F[1, 0] * F[2, 2] - F[1, 2] * F[2, 0])
            + F[0, 2] * (F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0])
        )
        if lam * vol[t] * h2 > 0.0:  # a volume stiffness that underflows to 0 has no constraint to enforce
            _cofactor(F, P)
            _grads(P, dm_inv[t], g)
            den = w[ids[0]] * _sq(g, 0) + w[ids[1]] * _sq(g, 1) + w[ids[2]] * _sq(g, 2) + w[ids[3]] * _sq(g, 3)
            alpha = 1.0 / (lam * vol[t] * h2)
            if den + alpha > 0.0:
                _apply(x, w, ids, g, -(J - 1.0) / (den + alpha))
        if abs(J - 1.0) > worst:
            worst = abs(J - 1.0)
    return worst


@njit(cache=True)
def tet_forces(x, tets, dm_inv, vol, active, mu, lam, gamma, stvk, out):
    """Elastic forces -dPsi/dx of the live tets' energy, added into out (N, 3).

    stvk False: the stable Neo-Hookean constraint energy V (mu/2 |F|^2 + lam/2 (J - gamma)^2), first
    Piola stress P = mu F + lam (J - gamma) cof F; stvk True: V (mu |E|^2 + lam/2 (J - 1)^2) with
    E = (F^T F - I)/2, P = 2 mu F E + lam (J - 1) cof F. Vertex k of a tet gets -V (P Dm^-T) column k.
    """
    g = np.zeros((4, 3))
    F = np.zeros((3, 3))
    P = np.zeros((3, 3))
    C = np.zeros((3, 3))
    E = np.zeros((3, 3))
    for t in range(tets.shape[0]):
        if not active[t]:
            continue
        _deformation(x, tets, dm_inv, t, F)
        _cofactor(F, C)
        J = F[0, 0] * C[0, 0] + F[1, 0] * C[1, 0] + F[2, 0] * C[2, 0]
        if stvk:
            for i in range(3):
                for j in range(3):
                    dot = F[0, i] * F[0, j] + F[1, i] * F[1, j] + F[2, i] * F[2, j]
                    E[i, j] = 0.5 * (dot - (1.0 if i == j else 0.0))
            for r in range(3):
                for c in range(3):
                    P[r, c] = 2.0 * mu * (F[r, 0] * E[0, c] + F[r, 1] * E[1, c] + F[r, 2] * E[2, c])
                    P[r, c] += lam * (J - 1.0) * C[r, c]
        else:
            for r in range(3):
                for c in range(3):
                    P[r, c] = mu * F[r, c] + lam * (J - gamma) * C[r, c]
        _grads(P, dm_inv[t], g)
        _add_forces(out, tets, t, vol[t], g)


@njit(cache=True)
def corot_sweep(x, w, tets, dm_inv, vol, active, mu, lam, h2, quats, rot_iterations, lam_d, lam_h):
    """One sweep of corotational tetrahedra (in place): a deviatoric constraint C_D = |F - R|_F with
    compliance 1/(2 mu V) and a volume constraint C_H = det F - 1 with compliance 1/(lam V), R the
    rotation of F. The energy V (mu |F - R|^2 + lam/2 (det F - 1)^2) is linear elasticity at small
    strain with the true Lame parameters, and both constraints are zero at rest, so a body left alone
    stays where it is whatever its stiffness, size and time step; the rest-biased Neo-Hookean pair
    above drifts and collapses once its compliance is small against the element's inverse mass.

    quats (T, 4) are the tets' rotations, warm-started across calls; lam_d / lam_h (T,) the
    multipliers of this substep. Returns max |det F - 1|.
    """
    g = np.zeros((4, 3))
    ids = np.zeros(4, dtype=np.int64)
    F = np.zeros((3, 3))
    P = np.zeros((3, 3))
    R = np.zeros((3, 3))
    worst = 0.0
    for t in range(tets.shape[0]):
        if not active[t]:
            continue
        for k in range(4):
            ids[k] = tets[t, k]
        a, b, c, d = ids[0], ids[1], ids[2], ids[3]
        if w[a] + w[b] + w[c] + w[d] == 0.0:
            continue
        _deformation(x, tets, dm_inv, t, F)
        rotation_into(F, quats[t], rot_iterations, R)
        # -- deviatoric: C = |F - R|, dC/dF = (F - R) / C (R's own change drops out: it is the closest
        # rotation, so |F - R|^2 is stationary in R)
        c2 = 0.0
        for r in range(3):
            for col in range(3):
                P[r, col] = F[r, col] - R[r, col]
                c2 += P[r, col] * P[r, col]
        C = np.sqrt(c2)
        kd = 2.0 * mu * vol[t] * h2
        if C > 1e-14 and kd > 0.0:
            inv = 1.0 / C
            for r in range(3):
                for col in range(3):
                    P[r, col] *= inv
            _grads(P, dm_inv[t], g)
            den = w[a] * _sq(g, 0) + w[b] * _sq(g, 1) + w[c] * _sq(g, 2) + w[d] * _sq(g, 3)
            alpha = 1.0 / kd
            dl = (-C - alpha * lam_d[t]) / (den + alpha)
            lam_d[t] += dl
            _apply(x, w, ids, g, dl)
            _deformation(x, tets, dm_inv, t, F)
        # -- volume: C = det F - 1, dC/dF = cofactor(F)
        _cofactor(F, P)
        J = F[0, 0] * P[0, 0] + F[1, 0] * P[1, 0] + F[2, 0] * P[2, 0]
        kv = lam * vol[t] * h2
        if kv > 0.0:
            _grads(P, dm_inv[t], g)
            den = w[a] * _sq(g, 0) + w[b] * _sq(g, 1) + w[c] * _sq(g, 2) + w[d] * _sq(g, 3)
            alpha = 1.0 / kv
            dl = (-(J - 1.0) - alpha * lam_h[t]) / (den + alpha)
            lam_h[t] += dl
            _apply(x, w, ids, g, dl)
        if abs(J - 1.0) > worst:
            worst = abs(J - 1.0)
    return worst


@njit(cache=True)
def corot_forces(x, tets, dm_inv, vol, active, mu, lam, quats, out):
    """Elastic forces -dPsi/dx of the corotational energy V (mu |F - R|^2 + lam/2 (J - 1)^2), added into
    out (N, 3): first Piola stress P = 2 mu (F - R) + lam (J - 1) cof F. quats are refined in place
    (pass a copy to leave a body's warm start alone)."""
    g = np.zeros((4, 3))
    F = np.zeros((3, 3))
    P = np.zeros((3, 3))
    C = np.zeros((3, 3))
    R = np.zeros((3, 3))
    for t in range(tets.shape[0]):
        if not active[t]:
            continue
        _deformation(x, tets, dm_inv, t, F)
        rotation_into(F, quats[t], 40, R)
        _cofactor(F, C)
        J = F[0, 0] * C[0, 0] + F[1, 0] * C[1, 0] + F[2, 0] * C[2, 0]
        for r in range(3):
            for c in range(3):
                P[r, c] = 2.0 * mu * (F[r, c] - R[r, c]) + lam * (J - 1.0) * C[r, c]
        _grads(P, dm_inv[t], g)
        _add_forces(out, tets, t, vol[t], g)


@njit(cache=True)
def corot_energy(x, tets, dm_inv, vol, active, mu, lam, quats):
    """The corotational energy sum V (mu |F - R|^2 + lam/2 (J - 1)^2) (quats refined in place)."""
    F = np.zeros((3, 3))
    R = np.zeros((3, 3))
    e = 0.0
    for t in range(tets.shape[0]):
        if not active[t]:
            continue
        _deformation(x, tets, dm_inv, t, F)
        rotation_into(F, quats[t], 40, R)
        J = np.linalg.det(F)
        s = 0.0
        for r in range(3):
            for c in range(3):
                s += (F[r, c] - R[r, c]) ** 2
        e += vol[t] * (mu * s + 0.5 * lam * (J - 1.0) ** 2)
    return e

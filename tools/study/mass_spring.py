"""Reference solver 3: a damped mass-spring network on the FEM mesh (thesis 2.3.2, eqs. 2.1-2.2).

Springs are the tetrahedron edges, masses are lumped (rho * V / 4 per corner).  The network is
integrated with explicit (forward) Euler or semi-implicit (symplectic) Euler, under viscous
damping, until it reaches static equilibrium with the grabbed nodes held at their targets.  The
critical time step of eq. (2.2) is computed next to the exact linearised bound, and a run whose
state blows up is stopped and reported with status "diverged" (its field is never returned).

Spring stiffness: k_e = E * W_e / L_e^2, with W_e one sixth of the volume of the tetrahedra that
share edge e (so the weights sum to the body's volume).  Under imposed displacements the static
field only depends on the ratios of the k_e, so this choice sets time scales, not the answer.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.csgraph as csgraph
import scipy.sparse.linalg as spla
from numba import njit

from .tetmesh import shape_gradients, tet_edges

EXPLICIT, SYMPLECTIC = 0, 1
SCHEMES = {"explicit": EXPLICIT, "symplectic": SYMPLECTIC}
_STATUS = {0: "converged", 1: "max_steps", 2: "diverged"}


@njit(cache=True)
def spring_forces(x, links, rest, k, out):
    """Internal spring forces into `out` (N, 3); returns the stored elastic energy."""
    out[:] = 0.0
    energy = 0.0
    for e in range(links.shape[0]):
        a = links[e, 0]
        b = links[e, 1]
        dx = x[b, 0] - x[a, 0]
        dy = x[b, 1] - x[a, 1]
        dz = x[b, 2] - x[a, 2]
        length = np.sqrt(dx * dx + dy * dy + dz * dz)
        ext = length - rest[e]
        energy += 0.5 * k[e] * ext * ext
        if length > 0.0:
            s = k[e] * ext / length
            out[a, 0] += s * dx
            out[a, 1] += s * dy
            out[a, 2] += s * dz
            out[b, 0] -= s * dx
            out[b, 1] -= s * dy
            out[b, 2] -= s * dz
    return energy


@njit(cache=True)
def integrate(
    x, v, links, rest, k, inv_m, gamma, free, dt, max_steps, scheme, tol, blowup, cidx, c0, cdisp, ramp_steps
):
    """Step until the free-node force residual falls below `tol` (absolute, 2-norm).

    The constrained nodes `cidx` move from c0 to c0 + cdisp linearly over `ramp_steps` steps (a
    tool moves gradually; a sudden jump of many link lengths folds springs onto themselves) and
    convergence is only tested once they have arrived.
    Returns (code, steps, residual): code 0 converged, 1 ran out of steps, 2 diverged (a
    coordinate went non-finite or further than `blowup` from the origin).  x, v updated in place.
    """
    n = x.shape[0]
    f = np.zeros((n, 3))
    resid = np.inf
    for step in range(1, max_steps + 1):
        if step <= ramp_steps + 1:
            w = min(1.0, step / max(ramp_steps, 1))
            for j in range(cidx.shape[0]):
                for d in range(3):
                    x[cidx[j], d] = c0[j, d] + w * cdisp[j, d]
        spring_forces(x, links, rest, k, f)
        resid2 = 0.0
        for i in range(n):
            if free[i]:
                for d in range(3):
                    resid2 += f[i, d] * f[i, d]
        resid = np.sqrt(resid2)
        if not np.isfinite(resid):
            return 2, step, resid
        if resid <= tol and step > ramp_steps:
            return 0, step - 1, resid
        for i in range(n):
            if not free[i]:
                continue
            for d in range(3):
                acc = f[i, d] * inv_m[i] - gamma * v[i, d]
                if scheme == 0:  # forward Euler: position uses the old velocity
                    x[i, d] += dt * v[i, d]
                    v[i, d] += dt * acc
                else:  # symplectic Euler: position uses the new velocity
                    v[i, d] += dt * acc
                    x[i, d] += dt * v[i, d]
                if not (abs(x[i, d]) < blowup):
                    return 2, step, resid
    return 1, max_steps, resid


@dataclass
class DynamicResult:
    u: np.ndarray | None  # (N, 3) or None when the run diverged
    status: str  # converged | max_steps | diverged
    steps: int
    residual: float
    dt: float
    info: dict = field(default_factory=dict)


class MassSpring:
    def __init__(self, pos, tets, E: float, rho: float = 1000.0, fixed=None):
        self.pos = np.ascontiguousarray(pos, dtype=np.float64)
        self.tets = np.asarray(tets, dtype=np.int64)
        vol, _ = shape_gradients(self.pos, self.tets)  # also rejects degenerate tets
        self.links = np.ascontiguousarray(tet_edges(self.tets))
        self.n = len(self.pos)
        self.rest = np.linalg.norm(self.pos[self.links[:, 1]] - self.pos[self.links[:, 0]], axis=1)
        # volume share of every edge: each tet gives 1/6 of its volume to each of its 6 edges
        pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
        e_all = np.sort(np.concatenate([self.tets[:, [a, b]] for a, b in pairs]), axis=1)
        key_all = e_all[:, 0] * self.n + e_all[:, 1]
        key = self.links[:, 0] * self.n + self.links[:, 1]
        idx = np.searchsorted(key, key_all)
        w = np.bincount(idx, weights=np.tile(vol / 6.0, 6), minlength=len(key))
        self.k = E * w / self.rest**2
        self.mass = np.bincount(self.tets.ravel(), weights=np.repeat(rho * vol / 4.0, 4), minlength=self.n)
        self.fixed = None if fixed is None else np.unique(np.asarray(fixed, dtype=np.int64))

    # --- time-step analysis (thesis eq. 2.2) ----------------------------------------------
    def critical_dt_eq22(self) -> float:
        """Delta t ~ (1/pi) sqrt(m_total / (n K_c)) with K_c the stiffest spring (eq. 2.2)."""
        return float(np.sqrt(self.mass.sum() / (self.n * self.k.max())) / np.pi)

    def linear_stiffness(self) -> sp.csr_matrix:
        """Stiffness of the network linearised at rest: k n n^T blocks per spring."""
        d = self.pos[self.links[:, 1]] - self.pos[self.links[:, 0]]
        nn = d / self.rest[:, None]
        blk = self.k[:, None, None] * nn[:, :, None] * nn[:, None, :]
        a, b = self.links[:, 0], self.links[:, 1]
        rows, cols, vals = [], [], []
        for p, q, s in ((a, a, 1), (b, b, 1), (a, b, -1), (b, a, -1)):
            rows.append((3 * p[:, None, None] + np.arange(3)[None, :, None]).repeat(3, 2).ravel())
            cols.append((3 * q[:, None, None] + np.arange(3)[None, None, :]).repeat(3, 1).ravel())
            vals.append((s * blk).ravel())
        return sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * self.n, 3 * self.n)
        )

    def omega_max(self, free_mask=None) -> float:
        """Highest angular frequency of the linearised network (free nodes only)."""
        K = self.linear_stiffness()
        minv = np.repeat(1.0 / np.sqrt(self.mass), 3)
        if free_mask is not None:
            sel = np.repeat(free_mask, 3)
            K, minv = K[sel][:, sel], minv[sel]
        A = (sp.diags(minv) @ K @ sp.diags(minv)).tocsr()
        lam = spla.eigsh(A, k=1, which="LA", return_eigenvectors=False, tol=1e-6)[0]
        # Gershgorin: a guaranteed upper bound, used when the Lanczos estimate falls short of it
        gersh = float(np.abs(A).sum(axis=1).max())
        self.last_omega_gershgorin = float(np.sqrt(gersh))
        return float(np.sqrt(max(lam, 0.0)))

    def omega_min_estimate(self, free_mask, anchored) -> float:
        """Rayleigh-quotient estimate of the slowest mode: a quarter sine of the hop distance
        from the anchored nodes, tried along each axis; used to pick near-critical damping."""
        n = self.n
        adj = sp.coo_matrix((np.ones(len(self.links)), (self.links[:, 0], self.links[:, 1])), shape=(n, n)).tocsr()
        dist = csgraph.dijkstra(adj, directed=False, indices=anchored, min_only=True, unweighted=True)
        dist[~np.isfinite(dist)] = 0
        shape = np.sin(0.5 * np.pi * dist / max(dist.max(), 1))
        shape[~free_mask] = 0
        K = self.linear_stiffness()
        best = np.inf
        for ax in range(3):
            u = np.zeros((n, 3))
            u[:, ax] = shape
            u = u.ravel()
            den = np.dot(u * np.repeat(self.mass, 3), u)
            if den > 0:
                best = min(best, float(np.dot(u, K @ u) / den))
        return float(np.sqrt(best))

    def analyse(self, free_mask, anchored):
        """(omega_max, Gershgorin bound, omega_min estimate) for one set of free nodes, cached."""
        key = (free_mask.tobytes(), np.asarray(anchored).tobytes())
        if getattr(self, "_analysis_key", None) != key:
            w_max = self.omega_max(free_mask)
            self._analysis = (w_max, self.last_omega_gershgorin, self.omega_min_estimate(free_mask, anchored))
            self._analysis_key = key
        return self._analysis

    # --- run to equilibrium -----------------------------------------------------------------
    def solve(
        self,
        constrained,
        disp_constrained,
        scheme="symplectic",
        dt=None,
        dt_factor=0.9,
        damping=None,
        tol=1e-4,
        max_steps=200_000,
        anchored=None,
        ramp=1.0,
    ) -> DynamicResult:
        """Hold `constrained` nodes at rest + disp and integrate to static equilibrium.

        dt defaults to dt_factor times the exact linear stability bound of the chosen scheme;
        damping (gamma = c/m) defaults to twice the slowest-mode frequency estimate.
        tol is relative to the force residual of the first step; the grabbed nodes reach their
        targets over `ramp` slowest-mode periods / (2 pi) (0: at once).
        """
        t0 = time.thread_time()
        c = np.asarray(constrained, dtype=np.int64)
        free = np.ones(self.n, np.bool_)
        free[c] = False
        anchored = self.fixed if anchored is None else anchored
        if anchored is None:
            anchored = c
        w_max, w_safe, w_min = self.analyse(free, anchored)
        gamma = 2.0 * w_min if damping is None else float(damping)
        # symplectic Euler is stable for dt < 2/w_max (undamped); forward Euler with viscous
        # damping gamma only for dt < gamma / w_max^2, far smaller when damping is light
        bound = 2.0 / w_max if SCHEMES[scheme] == SYMPLECTIC else gamma / w_max**2
        safe = 2.0 / w_safe if SCHEMES[scheme] == SYMPLECTIC else gamma / w_safe**2
        if dt is None:
            dt = dt_factor * safe
        x = self.pos.copy()
        cdisp = np.ascontiguousarray(np.asarray(disp_constrained, dtype=np.float64).reshape(-1, 3))
        ramp_steps = int(np.ceil(ramp / (w_min * dt))) if ramp > 0 else 0
        # residual scale: the forces of the fully displaced, not yet relaxed state
        x[c] += cdisp
        f = np.zeros_like(x)
        spring_forces(x, self.links, self.rest, self.k, f)
        r0 = float(np.linalg.norm(f[free]))
        x[c] = self.pos[c]
        v = np.zeros_like(x)
        t_setup = time.thread_time() - t0
        t1 = time.thread_time()
        blowup = 1e3 * (np.abs(self.pos).max() + np.abs(x).max() + 1.0)
        code, steps, resid = integrate(
            x, v, self.links, self.rest, self.k, 1.0 / self.mass, gamma, free, float(dt), int(max_steps),
            SCHEMES[scheme], tol * max(r0, 1e-300), blowup, c, np.ascontiguousarray(self.pos[c]), cdisp, ramp_steps,
        )  # fmt: skip
        t_run = time.thread_time() - t1
        status = _STATUS[int(code)]
        u = None if status == "diverged" or not np.all(np.isfinite(x)) else x - self.pos
        if u is None:
            status = "diverged"
        return DynamicResult(
            u,
            status,
            int(steps),
            float(resid / max(r0, 1e-300)),
            float(dt),
            {
                "t_setup": t_setup,
                "t_run": t_run,
                "t_step": t_run / max(steps, 1),
                "dt_bound": bound,
                "dt_gershgorin": safe,
                "dt_eq22": self.critical_dt_eq22(),
                "omega_max": w_max,
                "omega_min_est": w_min,
                "gamma": gamma,
                "ramp_steps": ramp_steps,
            },
        )

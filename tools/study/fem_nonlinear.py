"""Reference solver 2: geometrically nonlinear static FEM, compressible neo-Hookean P1 tetrahedra.

Ground truth for large deformation (thesis 2.3.2: nonlinear strain for large displacements).
Energy density  psi = mu/2 (I1 - 3) - mu ln J + lam/2 (ln J)^2.  Imposed displacements are
reached by load stepping (adaptive: a step that inverts an element is halved); each step is
solved by Newton's method with a backtracking (Armijo) line search on the total energy, inverted
states having infinite energy.  All element work is vectorised with numpy einsum.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse.linalg as spla

from .fem_linear import LOCKING_NU, LockingWarning, lame
from .sparse_assembly import SparsePattern, element_forces, element_matrices, scatter_forces
from .tetmesh import shape_gradients


@dataclass
class PathResult:
    """Solutions along a load path; `u[f]` is the (N,3) field at load fraction f."""

    u: dict
    status: str  # "converged" | "failed"
    newton_iterations: dict = field(default_factory=dict)
    load_steps: int = 0
    warnings: list[str] = field(default_factory=list)
    info: dict = field(default_factory=dict)


class NeoHookeanFEM:
    def __init__(self, pos, tets, E: float, nu: float, constrained):
        self.pos = np.asarray(pos, dtype=np.float64)
        self.tets = np.asarray(tets, dtype=np.int64)
        self.lam, self.mu = lame(E, nu)
        self.warnings: list[str] = []
        if nu > LOCKING_NU:
            msg = (
                f"nu={nu:g} > {LOCKING_NU}: P1 tetrahedra lock for nearly incompressible "
                "material; the nonlinear solution stays finite but is too stiff"
            )
            warnings.warn(msg, LockingWarning, stacklevel=2)
            self.warnings.append(msg)
        self.vol, self.grads = shape_gradients(self.pos, self.tets)
        self.n = len(self.pos)
        self.pattern = SparsePattern(self.tets, self.n)
        c = np.unique(np.asarray(constrained, dtype=np.int64))
        self.cdofs = (3 * c[:, None] + np.arange(3)).ravel()
        mask = np.ones(3 * self.n, bool)
        mask[self.cdofs] = False
        self.fdofs = np.flatnonzero(mask)
        self.constrained = c

    # --- element kinematics -------------------------------------------------------------
    def _deformation(self, u_flat):
        x = (self.pos.reshape(-1) + u_flat).reshape(-1, 3)[self.tets]  # (T,4,3)
        return np.einsum("tai,tak->tik", x, self.grads, optimize=True)  # F_ik

    def energy(self, u_flat) -> float:
        F = self._deformation(u_flat)
        J = np.linalg.det(F)
        if np.any(~(J > 0)):
            return np.inf
        lnJ = np.log(J)
        I1 = np.einsum("tik,tik->t", F, F)
        psi = 0.5 * self.mu * (I1 - 3) - self.mu * lnJ + 0.5 * self.lam * lnJ**2
        return float(np.dot(psi, self.vol))

    def residual_and_tangent(self, u_flat, want_tangent=True):
        F = self._deformation(u_flat)
        J = np.linalg.det(F)
        Finv = np.linalg.inv(F)  # (T,3,3)
        FinvT = np.transpose(Finv, (0, 2, 1))
        lnJ = np.log(J)
        P = self.mu * (F - FinvT) + self.lam * lnJ[:, None, None] * FinvT
        r = scatter_forces(self.tets, element_forces(self.vol, self.grads, P), self.n)
        if not want_tangent:
            return r, None
        d = np.eye(3)
        # A_ikjl = mu d_ij d_kl + (mu - lam lnJ) Finv_li Finv_kj + lam Finv_ki Finv_lj
        A = (
            self.mu * np.einsum("ij,kl->ikjl", d, d)[None]
            + (self.mu - self.lam * lnJ)[:, None, None, None, None]
            * np.einsum("tli,tkj->tikjl", Finv, Finv, optimize=True)
            + self.lam * np.einsum("tki,tlj->tikjl", Finv, Finv, optimize=True)
        )
        K = self.pattern.assemble(element_matrices(self.vol, self.grads, A))
        return r, K

    # --- solve ---------------------------------------------------------------------------
    def solve_path(
        self, disp_constrained, fractions, tol=1e-8, max_newton=30, max_halvings=8, initial_steps=None, progress=None
    ) -> PathResult:
        """Drive the constrained dofs to `fractions[i] * disp_constrained` in turn.

        disp_constrained: (len(constrained), 3) final prescribed displacements (np.unique order).
        Returns the fields at every requested fraction; status "failed" (with the fields reached
        so far) if Newton does not converge even after halving the load step max_halvings times.
        """
        t0 = time.thread_time()
        target = np.asarray(disp_constrained, dtype=np.float64).reshape(-1)
        fr = sorted(float(f) for f in fractions)
        u = np.zeros(3 * self.n)
        out: dict[float, np.ndarray] = {}
        iters: dict[float, int] = {}
        current, steps, total_newton = 0.0, 0, 0
        scale = None
        base_step = (fr[-1] / initial_steps) if initial_steps else None
        for f in fr:
            step = f - current if base_step is None else min(base_step, f - current)
            halvings = 0
            n_it_f = 0
            while current < f - 1e-12:
                step = min(step, f - current)
                trial = u.copy()
                trial[self.cdofs] = (current + step) * target
                ok, n_it, trial = self._newton(trial, u, tol, max_newton, scale)
                total_newton += n_it
                n_it_f += n_it
                if ok:
                    u = trial
                    current += step
                    steps += 1
                    if scale is None:
                        r, _ = self.residual_and_tangent(u, want_tangent=False)
                        scale = max(np.linalg.norm(r[self.cdofs]), 1e-300)
                    if progress:
                        progress(current)
                    if base_step is not None:
                        step = min(step * 1.5, base_step * 4)
                else:
                    halvings += 1
                    if halvings > max_halvings:
                        return PathResult(
                            out,
                            "failed",
                            iters,
                            steps,
                            list(self.warnings),
                            {"time": time.thread_time() - t0, "newton_total": total_newton, "reached": current},
                        )
                    step *= 0.5
            out[f] = u.reshape(-1, 3).copy()
            iters[f] = n_it_f
        return PathResult(
            out,
            "converged",
            iters,
            steps,
            list(self.warnings),
            {"time": time.thread_time() - t0, "newton_total": total_newton},
        )

    def _newton(self, trial, u_prev, tol, max_newton, scale):
        """Newton on the free dofs with the constrained ones already at their new values."""
        fd, cd = self.fdofs, self.cdofs
        # predictor: carry the prescribed increment into the interior with the current tangent,
        # so the first iterate does not crush the elements next to the moved nodes
        r, K = self.residual_and_tangent(u_prev)
        du_c = trial[cd] - u_prev[cd]
        if len(fd):
            Kff = K[fd][:, fd].tocsc()
            try:
                pred = spla.splu(Kff).solve(-(K[fd][:, cd] @ du_c) - r[fd])
                cand = trial.copy()
                cand[fd] = u_prev[fd] + pred
                if np.isfinite(self.energy(cand)):
                    trial = cand
            except RuntimeError:
                pass
        e = self.energy(trial)
        if not np.isfinite(e):
            return False, 0, trial
        ref = None
        for it in range(1, max_newton + 1):
            r, K = self.residual_and_tangent(trial)
            rf = r[fd]
            if ref is None:
                ref = max(scale if scale is not None else np.linalg.norm(r[cd]), 1e-300)
            if np.linalg.norm(rf) <= tol * ref:
                return True, it - 1, trial
            Kff = K[fd][:, fd].tocsc()
            try:
                du = spla.splu(Kff).solve(-rf)
            except RuntimeError:
                du = -rf
            if not np.all(np.isfinite(du)) or np.dot(du, rf) >= 0:
                # tangent not positive definite here: fall back to a scaled steepest descent
                du = -rf / max(Kff.diagonal().max(), 1e-300)
            slope = np.dot(du, rf)
            alpha = 1.0
            while alpha > 1e-8:
                cand = trial.copy()
                cand[fd] += alpha * du
                e_new = self.energy(cand)
                if np.isfinite(e_new) and e_new <= e + 1e-4 * alpha * slope + 1e-14 * abs(e):
                    break
                alpha *= 0.5
            else:
                return False, it, trial
            trial, e = cand, e_new
        r, _ = self.residual_and_tangent(trial, want_tangent=False)
        return bool(np.linalg.norm(r[fd]) <= tol * ref), max_newton, trial


def solve_neohookean(pos, tets, E, nu, constrained, disp_constrained, fractions=(1.0,), **kw):
    return NeoHookeanFEM(pos, tets, E, nu, constrained).solve_path(disp_constrained, fractions, **kw)

"""Reference solver 1: static linear-elastic FEM on P1 tetrahedra (thesis 2.3.2, eq. 2.4 F = KU).

Dirichlet conditions are applied by elimination (free/constrained partition of the dofs), so
imposed displacements are met exactly.  The free-free block is factorised once (scipy SuperLU);
each later load case is a pair of triangular solves, which is how a precomputed linear FEM runs
interactively (the pre-processing route of 2.3.2).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse.linalg as spla

from chainsim.systems.engine.errors import UserError

from .sparse_assembly import SparsePattern, element_matrices
from .tetmesh import shape_gradients

LOCKING_NU = 0.49


class LockingWarning(UserWarning):
    """Linear P1 tetrahedra lock (are far too stiff) as the Poisson ratio approaches 0.5."""


def check_material(E: float, nu: float) -> None:
    if not (np.isfinite(E) and E > 0):
        raise UserError(f"Young's modulus must be a positive number, got E={E!r}")
    if not (np.isfinite(nu) and -1.0 < nu < 0.5):
        raise UserError(f"Poisson ratio must lie in (-1, 0.5), got nu={nu!r}")


def lame(E: float, nu: float) -> tuple[float, float]:
    """Lame parameters (lambda, mu) of an isotropic material."""
    check_material(E, nu)
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    return lam, mu


def isotropic_tangent(lam: float, mu: float) -> np.ndarray:
    """C[i,k,j,l] with sigma_ik = C_ikjl du_j/dx_l (small strain)."""
    d = np.eye(3)
    return lam * np.einsum("ik,jl->ikjl", d, d) + mu * (np.einsum("ij,kl->ikjl", d, d) + np.einsum("il,kj->ikjl", d, d))


@dataclass
class StaticResult:
    u: np.ndarray  # (N, 3) displacements
    status: str  # "ok" | "failed"
    iterations: int = 1
    warnings: list[str] = field(default_factory=list)
    info: dict = field(default_factory=dict)


class LinearFEM:
    """Assemble and factorise once; `solve` then handles any imposed displacements / forces.

    constrained: node ids whose displacement is prescribed (fixed base and grabbed patch alike).
    """

    def __init__(self, pos, tets, E: float, nu: float, constrained):
        self.pos = np.asarray(pos, dtype=np.float64)
        self.tets = np.asarray(tets, dtype=np.int64)
        self.E, self.nu = float(E), float(nu)
        self.warnings: list[str] = []
        lam, mu = lame(E, nu)
        if nu > LOCKING_NU:
            msg = (
                f"nu={nu:g} > {LOCKING_NU}: linear P1 tetrahedra lock for nearly incompressible "
                "material; displacements stay finite but are too small"
            )
            warnings.warn(msg, LockingWarning, stacklevel=2)
            self.warnings.append(msg)
        t0 = time.thread_time()
        vol, grads = shape_gradients(self.pos, self.tets)
        self.n = len(self.pos)
        pattern = SparsePattern(self.tets, self.n)
        self.K = pattern.assemble(element_matrices(vol, grads, isotropic_tangent(lam, mu)))
        self.t_assemble = time.thread_time() - t0
        c = np.unique(np.asarray(constrained, dtype=np.int64))
        cd = (3 * c[:, None] + np.arange(3)).ravel()
        mask = np.ones(3 * self.n, bool)
        mask[cd] = False
        self.cdofs, self.fdofs = cd, np.flatnonzero(mask)
        self.constrained = c
        t0 = time.thread_time()
        Kf = self.K[self.fdofs][:, self.fdofs].tocsc()
        self.K_fc = self.K[self.fdofs][:, self.cdofs].tocsr()
        if len(self.fdofs) == 0:
            self.lu = None
        else:
            self.lu = spla.splu(Kf, permc_spec="COLAMD")
        self.t_factor = time.thread_time() - t0

    def solve(self, disp_constrained=None, forces=None) -> StaticResult:
        """disp_constrained: (len(constrained), 3) in the order of np.unique(constrained)."""
        u = np.zeros(3 * self.n)
        if disp_constrained is not None:
            u[self.cdofs] = np.asarray(disp_constrained, dtype=np.float64).reshape(-1)
        rhs = -(self.K_fc @ u[self.cdofs])
        if forces is not None:
            rhs += np.asarray(forces, dtype=np.float64).reshape(-1)[self.fdofs]
        t0 = time.thread_time()
        if self.lu is not None:
            u[self.fdofs] = self.lu.solve(rhs)
        t_solve = time.thread_time() - t0
        status = "ok" if np.all(np.isfinite(u)) else "failed"
        if status != "ok":
            u[~np.isfinite(u)] = 0.0
        return StaticResult(
            u.reshape(-1, 3),
            status,
            1,
            list(self.warnings),
            {"t_assemble": self.t_assemble, "t_factor": self.t_factor, "t_solve": t_solve},
        )


def solve_linear(pos, tets, E, nu, constrained, disp_constrained=None, forces=None) -> StaticResult:
    """One-shot convenience wrapper around LinearFEM."""
    return LinearFEM(pos, tets, E, nu, constrained).solve(disp_constrained, forces)

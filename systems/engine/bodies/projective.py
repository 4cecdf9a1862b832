"""Projective dynamics (Bouaziz et al. 2014) on tetrahedra: corotational linear elasticity written as
two projections, with a prefactorised sparse global system and local-global iterations warm-started
across frames. Through the body API.

Energy per tetrahedron (F the deformation gradient, R its polar rotation, V the rest volume):

    W = mu V |F - R|^2 + (lambda V / 2) (tr(R^T F) - 3)^2

the corotational energy of the FEM literature, linear elasticity at small strain. Both terms are
w / 2 |F - P|^2 with P the closest point of a set: R, nearest of the rotations (w = 2 mu V), and
F - (tr(R^T F) - 3) / 3 R, nearest of the matrices whose signed singular values sum to 3 (w = 3 lambda V,
since |F - P|^2 = (tr(R^T F) - 3)^2 / 3). So the local-global iteration is block descent on W (plus the
inertia term when dynamic) and `elastic_forces` is exactly -grad W: the stiffness is symmetric. The
volume term holds the sum of the principal stretches, not det F: at 10 % uniaxial stretch with
nu = 0.5 the volume shrinks by 0.7 % (stretches 1.1, 0.95, 0.95), a second-order error.

Fixed and grabbed elements are eliminated from the system exactly; the matrix is refactorised when the
set of held elements changes or a cut removes elements (the time it takes is kept in `stats`).

Stopping: the iterations converge linearly, slowly for nu near 0.5 (the global matrix carries the volume
weight in every direction, so the contraction per iteration is about 1 - 2 mu / (2 mu + 3 lambda): 0.93
at nu = 0.45, 0.9987 at 0.499), and a step's change is then far smaller than the remaining error. A
frame stops when the estimated distance to the solution, |step| / (1 - rate) with the rate measured
from successive steps, is below `tolerance` times the displacement scale (the largest of the imposed
grab displacement and the body's displacement from rest), so a creeping body keeps iterating.

Size: a sparse factorisation's fill grows about as the square of the node count on a solid mesh (here
0.09 s at 4k free nodes of a cube, 3.3 s at 22k, 11.5 s and 37M factor entries at 39k); above
`DIRECT_MAX_NODES` free nodes the default solver is CG, said in `notice`, and an explicit
`solver="direct"` is refused. When a frame's estimated CPU is past a 60 Hz frame (at the defaults, from
about 2k nodes of a solid block), `notice` says that too, with the nearest setting that fits
(chainsim.systems.engine.framecost).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.linalg import splu

from chainsim.systems.engine import framecost, meshgen
from chainsim.systems.engine.bodies.base import Body, Cells, StepStats, check_elastic
from chainsim.systems.engine.bodies.xpbd import lumped_mass, tet_rest_data
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels.graph import build_graph
from chainsim.systems.engine.kernels.projective import local_step, local_step_tri, pcg3
from chainsim.systems.engine.kernels.topology import cut_segment
from chainsim.systems.engine.model_params import PROJECTIVE_SOLVERS, defaults

MAX_ITERATIONS = 10_000
#: the global step: "direct" (sparse LU, factorised once per set of held elements) or "cg" (Jacobi-
#: preconditioned conjugate gradients, warm-started from the last frame, at most cg_iterations steps:
#: no factorisation, cheaper per frame on large meshes, more frames to converge)
SOLVERS = PROJECTIVE_SOLVERS
#: the body's defaults, from the one declaration of its parameters
_D = defaults("projective")
#: free nodes (not fixed) above which the direct solver is not used: its factorisation takes seconds and
#: hundreds of MB beyond this on a solid mesh, and grows about as the square of the count
DIRECT_MAX_NODES = 25_000
#: a step this small against the body's size is round-off: the iteration stands still
ROUNDOFF = 1e-13


class ProjectiveBody(Body):
    """Projective-dynamics body on tetrahedra; `dynamic=False` solves statics (no inertia term)."""

    model = "projective"
    # made by _prepare for the current step, held set and solver (None: to be made again)
    _factor: Any  # scipy's SuperLU factorisation of the free block
    _factor_key: tuple | None
    _rhs: np.ndarray | None
    _rate: float | None  # the last steps' convergence rate

    def __init__(
        self,
        rest: ArrayLike,
        tets: Cells | None = None,
        triangles: Cells | None = None,
        *,
        E: float = _D["E"],
        nu: float = _D["nu"],
        density: float = _D["density"],
        iterations: int = _D["iterations"],
        tolerance: float = 1e-6,
        damping: float = _D["damping"],
        dynamic: bool = _D["dynamic"],
        unit: float = _D["unit"],
        thickness: float = _D["thickness"],
        solver: str | None = _D["solver"],
        cg_iterations: int = _D["cg_iterations"],
        rotation_iterations: int = _D["rotation_iterations"],
        fixed: ArrayLike | None = None,
    ) -> None:
        super().__init__(rest, fixed)
        self.mu, self.lam = check_elastic(E, nu, density)
        if solver == "auto":
            solver = None  # the body chooses: direct up to DIRECT_MAX_NODES free nodes, CG above
        if solver is not None and solver not in SOLVERS:
            raise UserError(f"solver: expected one of {', '.join(SOLVERS)}, got {solver!r}")
        if not (math.isfinite(tolerance) and tolerance >= 0.0):
            raise UserError(f"tolerance: must be a finite number >= 0, got {tolerance}")
        #: a line saying what the body changed from what was asked (the solver it switched to), or ""
        self.notice = ""
        free_nodes = int(self.n - self.fixed.sum())
        if free_nodes > DIRECT_MAX_NODES:
            if solver == "direct":
                raise UserError(
                    f"solver: 'direct' cannot factorise {free_nodes} free nodes in reasonable time and memory "
                    f"(at most {DIRECT_MAX_NODES}); use solver='cg'"
                )
            if solver is None:
                self.notice = (
                    f"projective: {free_nodes} free nodes is above the direct solver's {DIRECT_MAX_NODES}; "
                    "using solver='cg'"
                )
                solver = "cg"
        solver = solver or "direct"
        if not (1 <= int(cg_iterations) <= MAX_ITERATIONS):
            raise UserError(f"cg_iterations: must be in 1..{MAX_ITERATIONS}, got {cg_iterations}")
        if not (1 <= int(rotation_iterations) <= 100):
            raise UserError(f"rotation_iterations: must be in 1..100, got {rotation_iterations}")
        self.solver, self.cg_iterations = solver, int(cg_iterations)
        # rotation refinements per local step; the rotations are warm-started from the last step, so one
        # is enough while the body moves slowly and costs a quarter of four (the local step's main cost)
        self.rotation_iterations = int(rotation_iterations)
        if tets is None or len(tets) == 0:
            if triangles is None or len(triangles) == 0:
                raise UserError("a projective-dynamics body needs tetrahedra or triangles")
            self._init_surface(triangles, iterations, tolerance, damping, dynamic, unit, thickness, density)
            return
        if not (1 <= int(iterations) <= MAX_ITERATIONS):
            raise UserError(f"iterations: must be in 1..{MAX_ITERATIONS}, got {iterations}")
        if not (0.0 <= damping < 1.0):
            raise UserError(f"damping: must be in [0, 1), got {damping}")
        self.tets = np.ascontiguousarray(tets, dtype=np.int64)
        if self.tets.ndim != 2 or self.tets.shape[1] != 4 or self.tets.min() < 0 or self.tets.max() >= self.n:
            raise UserError(f"tets: expected (T, 4) vertex ids in 0..{self.n - 1}")
        self.iterations, self.tolerance, self.damping = int(iterations), float(tolerance), float(damping)
        self.dynamic, self.unit = bool(dynamic), float(unit)
        rest_si = self.rest * self.unit
        dm_inv, self.vol = tet_rest_data(rest_si, self.tets)
        # D (T, 4, 3): F = X D with X = [x0 x1 x2 x3]; rows 1..3 are Dm^-1, row 0 minus their sum
        self.D = np.zeros((len(self.tets), 4, 3))
        self.D[:, 1:, :] = dm_inv
        self.D[:, 0, :] = -dm_inv.sum(axis=1)
        self.active = np.ones(len(self.tets), dtype=np.bool_)
        self.surface = False
        self.w_arap = 2.0 * self.mu * self.vol
        self.w_vol = 3.0 * self.lam * self.vol
        self.quats = np.zeros((len(self.tets), 4))
        self.quats[:, 0] = 1.0
        self.mass = lumped_mass(self.n, self.tets, self.vol, None, None, density)
        self.graph = build_graph(self.n, meshgen.links_from_cells(self.tets))
        self._init_state(rest_si)

    def _init_surface(self, triangles, iterations, tolerance, damping, dynamic, unit, thickness, density) -> None:
        """Membrane triangles (as-rigid-as-possible in their plane); no volume term, no bending."""
        tri = np.ascontiguousarray(triangles, dtype=np.int64)
        if tri.ndim != 2 or tri.shape[1] != 3 or tri.min() < 0 or tri.max() >= self.n:
            raise UserError(f"triangles: expected (F, 3) vertex ids in 0..{self.n - 1}")
        self.iterations, self.tolerance, self.damping = int(iterations), float(tolerance), float(damping)
        self.dynamic, self.unit = bool(dynamic), float(unit)
        rest_si = self.rest * self.unit
        p = rest_si[tri]
        e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
        area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
        if np.any(area <= 1e-12 * np.maximum(np.sum(e1 * e1, axis=1), 1e-300)):
            raise UserError("a triangle of the mesh is degenerate (zero area); the mesh cannot be simulated")
        u = e1 / np.linalg.norm(e1, axis=1)[:, None]
        nrm = np.cross(e1, e2)
        v = np.cross(nrm / np.linalg.norm(nrm, axis=1)[:, None], u)
        dm = np.stack(
            [np.stack([np.sum(e1 * u, 1), np.sum(e2 * u, 1)], 1), np.stack([np.sum(e1 * v, 1), np.sum(e2 * v, 1)], 1)],
            1,
        )
        dm_inv = np.linalg.inv(dm)  # (F, 2, 2): rest edges in the triangle's own plane
        self.tets = tri  # the element list (three corners each)
        self.D = np.zeros((len(tri), 3, 2))
        self.D[:, 1:, :] = dm_inv
        self.D[:, 0, :] = -dm_inv.sum(axis=1)
        self.vol = area * thickness * self.unit
        self.active = np.ones(len(tri), dtype=np.bool_)
        self.w_arap = 2.0 * self.mu * self.vol
        self.w_vol = np.zeros(len(tri))
        self.surface = True
        self.quats = np.zeros((0, 4))
        self.mass = lumped_mass(self.n, None, None, tri, self.vol, density)
        self.graph = build_graph(self.n, meshgen.links_from_polygons(tri))
        self._init_state(rest_si)

    def _init_state(self, rest_si: np.ndarray) -> None:
        """The state both kinds of element start from, and the notice of what a frame will cost (joined
        to the solver switch's, if any)."""
        self.x = rest_si.copy()
        self.v = np.zeros_like(self.x)
        self._factor = None
        self._factor_key = None
        self._rhs = None
        self._scale = max(float(np.ptp(rest_si, axis=0).max()), 1e-300)
        self.refactor_seconds = 0.0
        self._rate = None
        # the hybrid body builds on this set-up but runs its own iteration: this estimate is not its cost
        if self.model == "projective":
            self.notice = framecost.join(self.notice, framecost.projective_notice(self.frame_cost()))

    def frame_cost(self) -> framecost.ProjectiveFrame:
        """What a 60 Hz frame of this body is made of, for the estimate of its cost
        (chainsim.systems.engine.framecost)."""
        free = ~self.fixed
        factor = framecost.factor_entries(self.rest[free], self.surface) if self.solver == "direct" else 0.0
        return framecost.ProjectiveFrame(
            free=int(free.sum()),
            elements=int(self.active.sum()),
            surface=self.surface,
            dynamic=self.dynamic,
            matrix_entries=framecost.matrix_entries(free, self.graph.links),
            factor=factor,
            solver=self.solver,
            iterations=self.iterations,
            cg_iterations=self.cg_iterations,
            rotation_iterations=self.rotation_iterations,
        )

    @property
    def positions(self) -> np.ndarray:
        return self._positions

    @positions.setter
    def positions(self, value: np.ndarray) -> None:
        self._positions = value
        if hasattr(self, "x"):
            self.x[:] = np.asarray(value) * self.unit
            self._placed()

    def _placed(self) -> None:
        """Hook: the positions were set from outside the solve."""

    def set_materials(self, E: ArrayLike, nu: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Give each tetrahedron its own Young's modulus E (Pa) and Poisson's ratio nu (T,) in place of the
        one material the body was made with (a layered tissue); what was prepared from the old weights is
        made again. Returns the elements' Lame parameters (mu, lam). Equal values everywhere give exactly
        the body made with that material."""
        if self.surface:
            raise UserError("materials per element need tetrahedra (a sheet has one material)")
        T = len(self.tets)
        E = np.asarray(E, dtype=np.float64).reshape(-1)
        nu = np.asarray(nu, dtype=np.float64).reshape(-1)
        if len(E) != T or len(nu) != T:
            raise UserError(f"materials: expected one E and one nu per tetrahedron ({T}), got {len(E)} and {len(nu)}")
        for e, v in {(float(a), float(b)) for a, b in zip(E, nu)}:  # a few distinct pairs: one per layer
            check_elastic(e, v, 1.0)
        # the same operations as check_elastic's, element by element: equal inputs give equal bits
        mu = E / (2.0 * (1.0 + nu))
        lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
        self.w_arap = 2.0 * mu * self.vol
        self.w_vol = 3.0 * lam * self.vol
        self._factor, self._factor_key, self._rate = None, None, None
        return mu, lam

    def _stiffness(self) -> sp.csr_matrix:
        """Sum over live tets of (w_a + w_v) D D^T scattered to the corners (one matrix for x, y, z)."""
        t = self.tets[self.active]
        D = self.D[self.active]
        w = (self.w_arap + self.w_vol)[self.active]
        blocks = np.einsum("tkc,tlc->tkl", D, D) * w[:, None, None]
        k = t.shape[1]
        rows = np.repeat(t, k, axis=1).ravel()
        cols = np.tile(t, (1, k)).ravel()
        return sp.csr_matrix((blocks.ravel(), (rows, cols)), shape=(self.n, self.n))

    def _prepare(self, dt: float) -> None:
        held = self.fixed.copy()
        held[self.grab_ids] = True
        key = (held.tobytes(), self.active.tobytes(), dt if self.dynamic else None)
        if key == self._factor_key:
            return
        t0 = time.perf_counter()
        A = self._stiffness()
        if self.dynamic:
            A = A + sp.diags(self.mass / (dt * dt))
        free = np.flatnonzero(~held)
        self._free, self._held = free, np.flatnonzero(held)
        A = A.tocsc()
        self._A_fh = A[free][:, self._held]
        Aff = A[free][:, free]
        if len(free):
            # an element with no live tetrahedron (cut loose) and no inertia keeps its place
            diag = Aff.diagonal()
            if np.any(diag <= 0.0):
                Aff = Aff + sp.diags(np.where(diag <= 0.0, 1.0, 0.0))
                diag = Aff.diagonal()
            if self.solver == "cg":
                csr = Aff.tocsr()
                csr.sort_indices()
                self._csr = (csr.indptr.astype(np.int64), csr.indices.astype(np.int64), csr.data)
                self._inv_diag = 1.0 / diag
                self._scratch = [np.zeros((len(free), 3)) for _ in range(4)]
            else:
                # symmetric mode with a minimum-degree ordering of A + A^T: the matrix is SPD, so no
                # pivoting is needed, and the factors are about a third smaller than with COLAMD
                self._factor = splu(
                    Aff.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True}
                )
        self._factor_key = key
        self._rate = None  # a new system converges at its own rate
        self.refactor_seconds = time.perf_counter() - t0

    def _solve(self, dt: float) -> StepStats:
        t0 = time.perf_counter()
        self._prepare(dt)
        x = self.x
        x[self.grab_ids] = self.grab_targets * self.unit
        if self.dynamic:
            y = x + dt * self.v
        if self._rhs is None or self._rhs.shape != x.shape:
            self._rhs = np.zeros_like(x)
        rhs = self._rhs
        free, held = self._free, self._held
        prev = x.copy() if self.dynamic else x
        scale = self._scale
        # the displacement the answer is measured against: what the grab imposes, or how far the body
        # already is from rest (a body moving or relaxing with nothing grabbed)
        disp = float(np.max(np.abs(x - self.rest * self.unit))) if len(x) else 0.0
        floor = ROUNDOFF * (scale + float(np.max(np.abs(x)))) if len(x) else 0.0
        threshold = max(self.tolerance * disp, floor)
        error = math.inf
        last = 0.0
        done = 0
        for _ in range(self.iterations):
            done += 1
            if self.surface:
                local_step_tri(x, self.tets, self.D, self.active, self.w_arap, rhs)
            else:
                rot = self.rotation_iterations
                local_step(x, self.tets, self.D, self.active, self.w_arap, self.w_vol, self.quats, rot, rhs)
            if self.dynamic:
                rhs += (self.mass / (dt * dt))[:, None] * y
            if len(free) == 0:
                error = 0.0
                break
            b = rhs[free] - self._A_fh @ x[held]
            old = x[free]
            if self.solver == "cg":
                new = old.copy()
                pcg3(*self._csr, self._inv_diag, b, new, self.cg_iterations, 1e-10, *self._scratch)
            else:
                new = self._factor.solve(b)
            step = float(np.max(np.abs(new - old)))
            x[free] = new
            # converging linearly at rate rho, at most |step| rho / (1 - rho) is left to go; the rate is the
            # ratio of successive steps, carried over from the last frame for a frame's first step
            if last > 0.0:
                self._rate = step / last
            last = step
            if step <= floor:
                error = step
            elif self._rate is None or self._rate >= 1.0:
                error = math.inf
            else:
                error = step / (1.0 - self._rate)
            if error <= threshold:
                break
        if self.dynamic:
            self.v = (x - prev) / dt * (1.0 - self.damping)
            self.v[held] = 0.0
        np.divide(x, self.unit, out=self._positions)
        extra = {"refactor_s": self.refactor_seconds, "rate": self._rate, "solver": self.solver}
        if self.notice:
            extra["notice"] = self.notice
        # the estimated distance to the answer as a fraction of the displacement scale
        residual = error / disp if disp > 0.0 else (0.0 if error <= floor else math.inf)
        return StepStats(done, residual, 0, time.perf_counter() - t0, extra)

    def elastic_forces(self) -> np.ndarray:
        """Elastic forces (N, 3) in newtons in the current state: minus the gradient of the projective
        energy sum w/2 |F - proj(F)|^2, which is rhs(x) - L x with rhs the local step's right-hand side
        and L the global matrix (the projection minimises over its set, so it drops out of the gradient)."""
        rhs = np.zeros_like(self.x)
        if self.surface:
            local_step_tri(self.x, self.tets, self.D, self.active, self.w_arap, rhs)
        else:
            # a copy of the rotations, refined further, so asking for forces never changes the next step
            # refined to round-off: the forces are the energy's gradient only at the polar rotation
            local_step(self.x, self.tets, self.D, self.active, self.w_arap, self.w_vol, self.quats.copy(), 100, rhs)
        return rhs - self._stiffness() @ self.x

    def _cut(self, p0, p1, normal, depth) -> int:
        killed = cut_segment(self._positions, self.graph, p0, p1, normal=normal, depth=depth)
        if len(killed) == 0:
            return 0
        dead_set = {tuple(e) for e in np.sort(self.graph.links[killed], axis=1)}
        pairs = [[0, 1], [1, 2], [0, 2]] if self.surface else [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]
        edges = np.sort(self.tets[:, pairs], axis=2).reshape(-1, 2)
        hit = np.array([tuple(e) in dead_set for e in edges]).reshape(-1, len(pairs)).any(axis=1)
        self.active &= ~hit
        return int(len(killed))

    def reset(self) -> None:
        super().reset()
        self.x[:] = self.rest * self.unit
        self.v[:] = 0.0
        self.quats[:] = 0.0
        if len(self.quats):
            self.quats[:, 0] = 1.0

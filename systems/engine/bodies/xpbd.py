"""XPBD soft bodies: tetrahedral volumes with stable Neo-Hookean constraints, triangle surfaces with
stretch and bending distance constraints; substeps, damping, grabs as pinned targets, cuts that
remove constraints. The model of iMSTK's and NVIDIA's PBD trainers, through the body API.

Units: positions in the body's own length unit, `unit` metres each (1e-3 for millimetre meshes);
E in Pa, density in kg/m^3. The solve runs in SI so E and density mean what they say.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
from numpy.typing import ArrayLike

from chainsim.systems.engine import framecost, meshgen
from chainsim.systems.engine.bodies.base import Body, Cells, StepStats, check_elastic
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels.graph import build_graph
from chainsim.systems.engine.kernels.topology import cut_segment
from chainsim.systems.engine.kernels.xpbd import (
    corot_energy,
    corot_forces,
    corot_sweep,
    distance_sweep,
    stvk_sweep,
    tet_energy,
    tet_forces,
    tet_sweep,
)
from chainsim.systems.engine.model_params import XPBD_CONSTRAINTS, defaults

CONSTRAINTS = XPBD_CONSTRAINTS
#: the body's defaults, from the one declaration of its parameters
_D = defaults("xpbd")
#: says the substep shortfall on stderr as one line (the command line's logging, game/common/logs.py; with
#: no set-up, Python's last-resort handler prints the bare message): a Python warning would show a source path
logger = logging.getLogger(__name__)

MAX_SUBSTEPS = 1000
MAX_ITERATIONS = 1000
#: the substep rule: a shear wave may cross at most this fraction of the shortest edge per substep. Past
#: it the constraints act as nearly hard projections whose Gauss-Seidel fixed point is not the energy's
#: minimum: bodies come out too soft or too stiff and, pushed hard, elements invert (measured on 1 mm
#: tetrahedra at 10-100 kPa, docs/choosing-a-model.md). Below it XPBD approaches the implicit solution.
COURANT = 0.5


def tet_rest_data(rest_si: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse rest edge matrices (T,3,3) and rest volumes (T,) of tetrahedra; refuses degenerate ones."""
    p = rest_si[tets]
    dm = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)  # columns = edges
    det = np.linalg.det(dm)
    scale = np.max(np.abs(dm), axis=(1, 2)) ** 3 + 1e-300
    if np.any(np.abs(det) <= 1e-12 * scale):
        bad = int(np.flatnonzero(np.abs(det) <= 1e-12 * scale)[0])
        raise UserError(f"tetrahedron {bad} is degenerate (zero volume); the mesh cannot be simulated")
    return np.linalg.inv(dm), np.abs(det) / 6.0


def lumped_mass(
    n: int,
    tets: np.ndarray | None,
    vol: np.ndarray | None,
    tris: np.ndarray | None,
    area: np.ndarray | None,
    density: float,
) -> np.ndarray:
    """Each vertex's share of the mass of its tetrahedra (volume `vol`) or triangles (`area`)."""
    m = np.zeros(n)
    if tets is not None and len(tets):
        assert vol is not None  # given with the tetrahedra
        np.add.at(m, tets.ravel(), np.repeat(vol * density / 4.0, 4))
    if tris is not None and len(tris):
        assert area is not None  # given with the triangles
        np.add.at(m, tris.ravel(), np.repeat(area * density / 3.0, 3))
    m[m <= 0.0] = max(float(m.max()) if m.size else 1.0, 1e-12)  # isolated vertices get a mass too
    return m


class XPBDBody(Body):
    """XPBD body on tetrahedra (`tets`) or, without them, on surface triangles (`triangles`)."""

    model = "xpbd"
    # per-solve state, made on the first step after the held set changes (_grab_changed clears _w)
    vol: np.ndarray | None
    _w: np.ndarray | None
    _fixed_seen: np.ndarray

    def __init__(
        self,
        rest: ArrayLike,
        tets: Cells | None = None,
        triangles: Cells | None = None,
        *,
        E: float = _D["E"],
        nu: float = _D["nu"],
        density: float = _D["density"],
        damping: float = _D["damping"],
        substeps: int | str = _D["substeps"],
        iterations: int = _D["iterations"],
        thickness: float = _D["thickness"],
        bending: float = _D["bending"],
        unit: float = _D["unit"],
        gravity: ArrayLike = (0.0, 0.0, 0.0),
        constraints: str = _D["constraints"],
        fixed: ArrayLike | None = None,
    ) -> None:
        super().__init__(rest, fixed)
        self.mu, self.lam = check_elastic(E, nu, density)
        if not (0.0 <= damping < 1.0):
            raise UserError(f"damping: must be in [0, 1), got {damping}")
        if substeps != "auto" and not (
            isinstance(substeps, int | np.integer) and not isinstance(substeps, bool) and 1 <= substeps <= MAX_SUBSTEPS
        ):
            raise UserError(f"substeps: expected 'auto' or a whole number in 1..{MAX_SUBSTEPS}, got {substeps!r}")
        if not (1 <= int(iterations) <= MAX_ITERATIONS):
            raise UserError(f"iterations: must be in 1..{MAX_ITERATIONS}, got {iterations}")
        if not (unit > 0.0 and np.isfinite(unit)):
            raise UserError(f"unit: metres per length unit must be > 0, got {unit}")
        self.E, self.nu, self.density = float(E), float(nu), float(density)
        self.damping, self.iterations = float(damping), int(iterations)
        self.substeps_setting = substeps if substeps == "auto" else int(substeps)
        self.substeps = 1 if substeps == "auto" else int(substeps)  # the count the last step used
        self._substeps_for: dict[float, int] = {}
        self.unit = float(unit)
        self.gravity = np.asarray(gravity, dtype=np.float64)
        if constraints not in CONSTRAINTS:
            raise UserError(f"constraints: expected one of {', '.join(CONSTRAINTS)}, got {constraints!r}")
        # "auto" is the corotational pair (|F - R| and det F - 1): both zero at rest, so a body left alone
        # stays put at any stiffness, size and step. The stable Neo-Hookean pair (|F| and det F - gamma)
        # balances two nonzero constraints at rest and, once its compliance is small against an
        # element's inverse mass (millimetre elements, tens of kPa), drifts and collapses; it stays
        # available by name, as does the Green-strain (StVK) set.
        if constraints == "auto":
            constraints = "corotational"
        self.constraints = constraints
        # Smith, de Goes and Kim's reparameterisation (stable Neo-Hookean, their 3.4): the energy
        # mu/2 |F|^2 + l/2 (J - 1 - mu/l)^2 linearises to linear elasticity with Lame lambda = l - mu,
        # so the hydrostatic weight is l = lambda + mu. With l = lambda the body was softer in volume
        # than (E, nu) say: at nu = 0.3 its small-strain lambda was a third of the right one.
        self.lam_eff = self.lam + self.mu
        self.gamma = 1.0 + self.mu / self.lam_eff
        rest_si = self.rest * self.unit
        self.tets = None if tets is None or len(tets) == 0 else np.ascontiguousarray(tets, dtype=np.int64)
        if self.tets is not None:
            if self.tets.ndim != 2 or self.tets.shape[1] != 4 or self.tets.min() < 0 or self.tets.max() >= self.n:
                raise UserError(f"tets: expected (T, 4) vertex ids in 0..{self.n - 1}")
            self.dm_inv, self.vol = tet_rest_data(rest_si, self.tets)
            links = meshgen.links_from_cells(self.tets)
            self.tet_active = np.ones(len(self.tets), dtype=np.bool_)
            self.quats = np.zeros((len(self.tets), 4))
            self.quats[:, 0] = 1.0
            tri, area = None, None
        else:
            if triangles is None or len(triangles) == 0:
                raise UserError("an XPBD body needs tetrahedra or triangles")
            tri = np.ascontiguousarray(triangles, dtype=np.int64)
            if tri.ndim != 2 or tri.shape[1] != 3 or tri.min() < 0 or tri.max() >= self.n:
                raise UserError(f"triangles: expected (F, 3) vertex ids in 0..{self.n - 1}")
            p = rest_si[tri]
            area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1) * thickness * self.unit
            links = meshgen.links_from_polygons(tri)
            self.vol = None
        self.triangles = tri
        self.graph = build_graph(self.n, links)  # the edges a blade can cut
        # distance constraints: surface stretch on edges, bending across each interior edge
        self.pairs, self.rest_len, self.compliance, self.pair_link = self._distance_constraints(
            rest_si, thickness, bending
        )
        self.pair_active = np.ones(len(self.pairs), dtype=np.bool_)
        self.mass = lumped_mass(self.n, self.tets, self.vol, tri, area, self.density)
        # the fastest wave the substep rule must resolve: shear in a volume, stretch in a sheet
        self.wave_speed = math.sqrt((self.mu if self.tets is not None else self.E) / self.density)
        lk = self.graph.links
        edge = np.linalg.norm(rest_si[lk[:, 0]] - rest_si[lk[:, 1]], axis=1) if len(lk) else np.ones(1)
        self.min_edge = float(max(edge.min(), 1e-300))
        self.x, self.v = rest_si.copy(), np.zeros_like(rest_si)
        self.notice = framecost.xpbd_notice(self.frame_cost())  # a line when a frame costs more than 60 Hz allows

    def _distance_constraints(self, rest_si, thickness, bending):
        if self.tets is not None:
            return np.zeros((0, 2), np.int64), np.zeros(0), np.zeros(0), np.zeros(0, np.int64)
        links = self.graph.links
        length = np.linalg.norm(rest_si[links[:, 0]] - rest_si[links[:, 1]], axis=1)
        k_stretch = self.E * thickness * self.unit  # N/m per unit width: compliance 1/(E t)
        pairs, rest_len, comp, owner = (
            [links],
            [length],
            [np.full(len(links), 1.0 / k_stretch)],
            [np.arange(len(links))],
        )
        # bending: the two vertices opposite each interior edge, held at their rest distance, softer
        tri = self.triangles
        e = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
        opp = np.concatenate([tri[:, 2], tri[:, 0], tri[:, 1]])
        order = np.lexsort((e[:, 1], e[:, 0]))
        e, opp = e[order], opp[order]
        same = np.all(e[1:] == e[:-1], axis=1)
        a, b = opp[:-1][same], opp[1:][same]
        if len(a):
            key = {tuple(lk): i for i, lk in enumerate(map(tuple, links))}
            edge_id = np.array([key[tuple(x)] for x in e[:-1][same]], dtype=np.int64)
            bl = np.linalg.norm(rest_si[a] - rest_si[b], axis=1)
            pairs.append(np.stack([a, b], axis=1))
            rest_len.append(bl)
            comp.append(np.full(len(a), 1.0 / (k_stretch * max(bending, 1e-12))))
            owner.append(edge_id)
        return (
            np.ascontiguousarray(np.concatenate(pairs), dtype=np.int64),
            np.concatenate(rest_len),
            np.concatenate(comp),
            np.concatenate(owner),
        )

    # -- the API --------------------------------------------------------------------------------
    @property
    def positions(self) -> np.ndarray:
        return self._positions

    @positions.setter
    def positions(self, value: np.ndarray) -> None:
        self._positions = value
        if hasattr(self, "x"):
            self.x[:] = np.asarray(value) * self.unit

    def _grab_changed(self) -> None:
        self._w = None  # the inverse masses change with the held set

    def substeps_needed(self, dt: float) -> int:
        """Substeps the rule asks for at frame step dt: a shear (surfaces: stretch) wave crosses at most
        COURANT of the shortest edge per substep."""
        return max(1, math.ceil(dt * self.wave_speed / (COURANT * self.min_edge) - 1e-9))

    def frame_cost(self) -> framecost.XPBDFrame:
        """What a 60 Hz frame of this body is made of, for the estimate of its cost
        (chainsim.systems.engine.framecost)."""
        rule = self.substeps_needed(framecost.FRAME_S)
        by_rule = self.substeps_setting == "auto"
        tets = int(self.tet_active.sum()) if self.tets is not None else 0
        substeps = rule if by_rule else int(self.substeps_setting)
        return framecost.XPBDFrame(
            self.n, tets, len(self.pairs), self.constraints, substeps, rule, by_rule, self.iterations
        )

    def _resolve_substeps(self, dt: float) -> int:
        n = self._substeps_for.get(dt)
        if n is not None:
            return n
        need = self.substeps_needed(dt)
        what = (
            f"xpbd: {self.min_edge * 1e3:.3g} mm elements at E = {self.E:g} Pa need {need} substeps per "
            f"{dt * 1e3:.3g} ms step (a wave crosses {COURANT} of an element per substep)"
        )
        if self.substeps_setting == "auto":
            if need > MAX_SUBSTEPS:
                raise UserError(
                    f"{what}, more than the {MAX_SUBSTEPS} allowed: use projective, coarser elements or a shorter step"
                )
            n = need
        else:
            n = int(self.substeps_setting)
            if n < need:
                # honoured (a researcher may measure exactly this), but never silently: said once per step
                # length, and kept in the notice beside the frame's cost
                line = f"{what}; {n} given, so the body may come out too soft or invert under a hard pull"
                self.notice = framecost.join(framecost.xpbd_notice(self.frame_cost()), line)
                logger.warning("%s", line)
        self._substeps_for[dt] = n
        return n

    def _solve(self, dt: float) -> StepStats:
        t0 = time.perf_counter()
        self.substeps = self._resolve_substeps(dt)
        h = dt / self.substeps
        h2 = h * h
        if getattr(self, "_w", None) is None or not np.array_equal(self._fixed_seen, self.fixed):
            self._fixed_seen = self.fixed.copy()
            w = np.where(self.fixed, 0.0, 1.0 / self.mass)
            w[self.grab_ids] = 0.0
            self._w, self._pinned = w, w == 0.0
            nt = len(self.tets) if self.tets is not None else 0
            self._lam_d, self._lam_h, self._lam_p = np.zeros(nt), np.zeros(nt), np.zeros(len(self.pairs))
            self._prev = np.empty_like(self.x)
        assert self._w is not None  # made just above when it was missing
        w, lam_d, lam_h, lam_p, prev = self._w, self._lam_d, self._lam_h, self._lam_p, self._prev
        target = self.grab_targets * self.unit
        start = self.x[self.grab_ids].copy()
        gravity = bool(np.any(self.gravity != 0.0))
        worst = 0.0
        for s in range(self.substeps):
            prev[:] = self.x
            if gravity:
                self.v += h * self.gravity * (w > 0.0)[:, None]
            self.x += h * self.v
            # grabbed elements travel to their targets over the step (no teleporting impulse)
            f = (s + 1) / self.substeps
            self.x[self.grab_ids] = start + f * (target - start)
            lam_d[:] = 0.0
            lam_h[:] = 0.0
            lam_p[:] = 0.0
            for _ in range(self.iterations):
                if self.tets is not None and self.constraints == "corotational":
                    worst = corot_sweep(
                        self.x,
                        w,
                        self.tets,
                        self.dm_inv,
                        self.vol,
                        self.tet_active,
                        self.mu,
                        self.lam,
                        h2,
                        self.quats,
                        2,
                        lam_d,
                        lam_h,
                    )
                elif self.tets is not None and self.constraints == "stvk":
                    worst = stvk_sweep(
                        self.x, w, self.tets, self.dm_inv, self.vol, self.tet_active, self.mu, self.lam, h2
                    )
                elif self.tets is not None:
                    worst = tet_sweep(
                        self.x,
                        w,
                        self.tets,
                        self.dm_inv,
                        self.vol,
                        self.tet_active,
                        self.mu,
                        self.lam_eff,
                        self.gamma,
                        h2,
                        lam_d,
                        lam_h,
                    )
                if len(self.pairs):
                    worst = distance_sweep(
                        self.x, w, self.pairs, self.rest_len, self.compliance, self.pair_active, h2, lam_p
                    )
            # v = (x - prev) / h * (1 - damping), in place
            np.subtract(self.x, prev, out=self.v)
            self.v *= (1.0 - self.damping) / h
            self.v[self._pinned] = 0.0
        self._positions[:] = self.x / self.unit
        return StepStats(self.substeps * self.iterations, float(worst), 0, time.perf_counter() - t0)

    def _cut(self, p0, p1, normal, depth) -> int:
        killed = cut_segment(self._positions, self.graph, p0, p1, normal=normal, depth=depth)
        if len(killed) == 0:
            return 0
        dead = np.zeros(self.graph.n_links, dtype=np.bool_)
        dead[killed] = True
        if self.tets is not None:
            # a tetrahedron with a cut edge no longer holds together
            lk = self.graph.links
            edges = np.sort(self.tets[:, [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]], axis=2).reshape(-1, 2)
            dead_set = {tuple(x) for x in np.sort(lk[killed], axis=1)}
            hit = np.array([tuple(e) in dead_set for e in edges]).reshape(-1, 6).any(axis=1)
            self.tet_active &= ~hit
        if len(self.pairs):
            self.pair_active &= ~dead[self.pair_link]
        return int(len(killed))

    def reset(self) -> None:
        super().reset()
        self.x[:] = self.rest * self.unit
        self.v[:] = 0.0
        if self.tets is not None:
            self.quats[:] = 0.0
            self.quats[:, 0] = 1.0

    def elastic_forces(self) -> np.ndarray:
        """Elastic forces (N, 3) in newtons on every element in the current state: minus the gradient of
        the constraint energy (Neo-Hookean or StVK tetrahedra; stretch and bending springs on surfaces).
        At rest they vanish; at small strain they are linear FEM's -K u for the same (E, nu)."""
        f = np.zeros_like(self.x)
        if self.tets is not None and self.constraints == "corotational":
            corot_forces(
                self.x, self.tets, self.dm_inv, self.vol, self.tet_active, self.mu, self.lam, self.quats.copy(), f
            )
        elif self.tets is not None:
            stvk = self.constraints == "stvk"
            lam = self.lam if stvk else self.lam_eff
            tet_forces(self.x, self.tets, self.dm_inv, self.vol, self.tet_active, self.mu, lam, self.gamma, stvk, f)
        if len(self.pairs):
            a, b = self.pairs[:, 0], self.pairs[:, 1]
            d = self.x[a] - self.x[b]
            ln = np.maximum(np.linalg.norm(d, axis=1), 1e-300)
            k = np.where(self.pair_active, 1.0 / self.compliance, 0.0)
            fa = -(k * (ln - self.rest_len) / ln)[:, None] * d  # C = |d| - L, force on a: -k C d/|d|
            np.add.at(f, a, fa)
            np.add.at(f, b, -fa)
        return f

    def energy(self) -> dict:
        """Kinetic and elastic energy (J) of the current state: a check that nothing blows up."""
        kin = 0.5 * float(np.sum(self.mass[:, None] * self.v**2))
        el = 0.0
        if self.tets is not None and self.constraints == "corotational":
            q = self.quats.copy()
            el = float(corot_energy(self.x, self.tets, self.dm_inv, self.vol, self.tet_active, self.mu, self.lam, q))
        elif self.tets is not None:
            el = float(
                tet_energy(self.x, self.tets, self.dm_inv, self.vol, self.tet_active, self.mu, self.lam_eff, self.gamma)
            )
            rest_e = float(
                tet_energy(
                    self.rest * self.unit,
                    self.tets,
                    self.dm_inv,
                    self.vol,
                    self.tet_active,
                    self.mu,
                    self.lam_eff,
                    self.gamma,
                )
            )
            el -= rest_e
        if len(self.pairs):
            d = np.linalg.norm(self.x[self.pairs[:, 0]] - self.x[self.pairs[:, 1]], axis=1) - self.rest_len
            el += float(np.sum(self.pair_active * 0.5 * d**2 / self.compliance))
        return {"kinetic": kin, "elastic": el}

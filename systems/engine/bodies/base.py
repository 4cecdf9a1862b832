"""The body API every deformation model implements, and the checks they share."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TypeAlias

import numpy as np
from numpy.typing import ArrayLike

from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels.graph import Graph
from chainsim.systems.engine.kernels.rows import changed_rows

#: the most elements a single grab may hold (bounds memory and per-step cost of attachments)
MAX_GRAB = 1_000_000

#: cells or links as the bodies take them: an (N, k) index array or a list of k-lists (they take its
#: len(), which a general ArrayLike such as a scalar does not have)
Cells: TypeAlias = np.ndarray | Sequence[Sequence[int]]


@dataclass
class StepStats:
    """What the last step did: iterations run, the residual reached, elements moved, seconds spent."""

    iterations: int = 0
    residual: float = 0.0
    moved: int = 0
    seconds: float = 0.0
    extra: dict = field(default_factory=dict)


def check_positions(name: str, x: ArrayLike, n: int | None = None) -> np.ndarray:
    """(K, 3) finite float64 array or UserError naming `name`."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 1 and a.size == 3:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 3:
        raise UserError(f"{name}: expected (K, 3) coordinates, got shape {a.shape}")
    if n is not None and len(a) != n:
        raise UserError(f"{name}: expected {n} points, got {len(a)}")
    if not np.all(np.isfinite(a)):
        raise UserError(f"{name}: coordinates must be finite numbers")
    if np.any(np.abs(a) > 1e12):
        raise UserError(f"{name}: coordinates must be within +-1e12")
    return a


def check_ids(name: str, ids: ArrayLike, n: int) -> np.ndarray:
    """int64 element ids in [0, n) or UserError."""
    a = np.atleast_1d(np.asarray(ids))
    if a.size and not np.issubdtype(a.dtype, np.integer):
        raise UserError(f"{name}: element ids must be integers")
    a = a.astype(np.int64).ravel()
    if a.size > MAX_GRAB:
        raise UserError(f"{name}: at most {MAX_GRAB} elements, got {a.size}")
    if a.size and (a.min() < 0 or a.max() >= n):
        raise UserError(f"{name}: element ids must be in 0..{n - 1}")
    return a


def check_elastic(E: float, nu: float, density: float) -> tuple[float, float]:
    """Lame parameters (mu, lam) from Young's modulus and Poisson's ratio, or UserError."""
    for name, v in (("E", E), ("nu", nu), ("density", density)):
        if not math.isfinite(v):
            raise UserError(f"{name}: must be a finite number, got {v}")
    if not 0.0 < E <= 1e12:
        raise UserError(f"E: Young's modulus must be in (0, 1e12] Pa, got {E:g}")
    if not 0.0 <= nu < 0.5:
        raise UserError(f"nu: Poisson's ratio must be in [0, 0.5) (0.5 is incompressible), got {nu:g}")
    if not 0.0 < density <= 1e6:
        raise UserError(f"density: must be in (0, 1e6] kg/m^3, got {density:g}")
    mu = E / (2.0 * (1.0 + nu))
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    return mu, lam


def check_dt(dt: float) -> float:
    if not (math.isfinite(dt) and 0.0 < dt <= 1.0):
        raise UserError(f"dt: time step must be in (0, 1] s, got {dt}")
    return float(dt)


class Body:
    """A soft body: `positions` (N, 3) in its own frame, grabbed elements driven to targets.

    Subclasses set `rest`, `positions`, `fixed` (bool mask) and implement `_solve(dt)` and `_cut(...)`.
    """

    model = "body"
    graph: Graph  # every model builds one: the links a blade can cut

    def __init__(self, rest: ArrayLike, fixed: ArrayLike | None = None) -> None:
        self.rest = check_positions("rest positions", rest).copy()
        n = len(self.rest)
        self.positions = self.rest.copy()
        self.fixed = np.zeros(n, dtype=np.bool_)
        if fixed is not None:
            f = np.asarray(fixed)
            if f.dtype == np.bool_ and f.shape == (n,):
                self.fixed[:] = f
            else:
                self.fixed[check_ids("fixed", f, n)] = True
        self.grab_ids = np.zeros(0, dtype=np.int64)
        self.grab_targets = np.zeros((0, 3))
        self.moved = np.zeros(0, dtype=np.int64)
        self.stats = StepStats()
        self._kept = False  # set by a _solve that wrote no position this step

    @property
    def n(self) -> int:
        return len(self.rest)

    def grab(self, ids: ArrayLike, targets: ArrayLike) -> None:
        """Hold elements `ids` at `targets` (K, 3) from the next step on (replaces any current grab)."""
        ids = check_ids("grab ids", ids, self.n)
        t = check_positions("grab targets", targets)
        if len(t) == 1 and len(ids) > 1:
            t = np.repeat(t, len(ids), axis=0)
        if len(t) != len(ids):
            raise UserError(f"grab: {len(ids)} ids but {len(t)} targets")
        keep = ~self.fixed[ids]  # fixed elements never move, even when grabbed
        self.grab_ids, self.grab_targets = ids[keep], t[keep]
        self._grab_changed()

    def release(self, ids: ArrayLike | None = None) -> None:
        """Let go of all grabbed elements, or only `ids`."""
        if ids is None:
            self.grab_ids, self.grab_targets = np.zeros(0, dtype=np.int64), np.zeros((0, 3))
        else:
            keep = ~np.isin(self.grab_ids, check_ids("release ids", ids, self.n))
            self.grab_ids, self.grab_targets = self.grab_ids[keep], self.grab_targets[keep]
        self._grab_changed()

    def step(self, dt: float = 1.0 / 60.0) -> StepStats:
        """Advance by `dt` seconds (static models solve for the current grab)."""
        before = self.positions.copy()
        self._kept = False
        stats = self._solve(check_dt(dt))
        if self._kept:  # the solve wrote no position (it says so): none moved, and they were finite before
            moved, finite = np.zeros(0, dtype=np.int64), True
        else:
            moved, finite = changed_rows(self.positions, before)
        self.moved = moved
        stats.moved = len(moved)
        if not finite:  # never hand back a NaN: restore and say so
            self.positions[:] = before
            raise UserError(f"{self.model}: the step diverged (non-finite positions); lower dt or stiffness")
        self.stats = stats
        return stats

    def cut(self, p0: ArrayLike, p1: ArrayLike, normal: ArrayLike | None = None, depth: float | None = None) -> int:
        """Cut along the segment p0-p1 (a blade swept along `normal`); returns how many links died."""
        return self._cut(check_positions("cut p0", p0)[0], check_positions("cut p1", p1)[0], normal, depth)

    def cut_path(self, points: ArrayLike, normal: ArrayLike | None = None, depth: float | None = None) -> int:
        pts = check_positions("cut path", points)
        return sum(self._cut(a, b, normal, depth) for a, b in zip(pts[:-1], pts[1:]))

    def elastic_forces(self) -> np.ndarray | None:
        """Elastic forces (N, 3) in newtons in the current state (minus the energy gradient), or None for a
        model without a force model (ChainMail: its limits are geometry, not an energy)."""
        return None

    def grab_force(self) -> np.ndarray | None:
        """The force (3,) in newtons the grab applies to the body to hold its elements where they are:
        minus the sum of the elastic forces on the grabbed elements (the tool feels its opposite). At
        equilibrium this is the grab's reaction force. None where the model has no forces (ChainMail)."""
        f = self.elastic_forces()
        if f is None:
            return None
        return -f[self.grab_ids].sum(axis=0) if len(self.grab_ids) else np.zeros(3)

    def reset(self) -> None:
        """Back to rest (cuts stay; a new body undoes them)."""
        self.positions[:] = self.rest
        self.release()

    # -- for subclasses -----------------------------------------------------------------------
    def _grab_changed(self) -> None:
        pass

    def _solve(self, dt: float) -> StepStats:  # pragma: no cover - abstract
        raise NotImplementedError

    def _cut(self, p0, p1, normal, depth) -> int:  # pragma: no cover - abstract
        raise NotImplementedError

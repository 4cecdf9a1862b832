"""Generalised ChainMail through the body API (thesis 5.2): the cascade, relaxation and the exact-limit
pass for one body, in one place.

ChainMail is quasi-static: `grab` (or `move`) runs the cascade at once from the current shape, then
relaxation (5.2.5) and, with `exact`, the pass that puts every link of the moved region back in its
limits; `step` has nothing left to do. Works for positions of dimension 1, 2 or 3 and in float32.
"""

from __future__ import annotations

import time

import numba
import numpy as np
from numpy.typing import ArrayLike

from chainsim.systems.engine.bodies.base import Body, Cells, StepStats, check_ids
from chainsim.systems.engine.chainmail_params import order_code
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels import topology
from chainsim.systems.engine.kernels.chainmail import cascade, make_workspace, material_arrays
from chainsim.systems.engine.kernels.exact import ExactResult, exact_limits, exact_move
from chainsim.systems.engine.kernels.graph import Graph, build_graph
from chainsim.systems.engine.kernels.relax import relax
from chainsim.systems.engine.model_params import PER_LINK, defaults

#: below this many active elements relaxation runs on one thread: a parallel region's barriers cost
#: far more than the work when the machine is busy (measured ~100x slower for a 1000-element patch)
PARALLEL_RELAX_MIN = 100_000
#: the body's defaults, from the one declaration of its parameters
_D = defaults("chainmail")


def relax_moved(
    rest: ArrayLike,
    pos: ArrayLike,
    graph: Graph,
    active: np.ndarray,
    iterations: int,
    step: float = 1.0,
    fixed: ArrayLike | None = None,
) -> None:
    """Relaxation of thesis 5.2.5 over `active` (chainsim.systems.engine.kernels.relax), serial for small sets."""
    if len(active) >= PARALLEL_RELAX_MIN:
        relax(rest, pos, graph, active, iterations, step=step, fixed=fixed)
        return
    previous = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        relax(rest, pos, graph, active, iterations, step=step, fixed=fixed)
    finally:
        numba.set_num_threads(previous)


def link_limits(n_links: int, alpha_min: ArrayLike, alpha_max: ArrayLike, beta: ArrayLike) -> tuple[np.ndarray, ...]:
    """Per-link (amin, amax, beta): a scalar fills every link; an array of one float64 value per link is
    used as it is, not copied (the component that built it reads the body's limits through it)."""
    if all(np.ndim(v) == 0 for v in (alpha_min, alpha_max, beta)):
        return material_arrays(n_links, alpha_min, alpha_max, beta)
    out = []
    for name, value in (("alpha_min", alpha_min), ("alpha_max", alpha_max), ("beta", beta)):
        if np.ndim(value) == 0:
            out.append(np.full(n_links, value, dtype=np.float64))
            continue
        arr = np.ascontiguousarray(value, dtype=np.float64)
        if arr.shape != (n_links,):
            raise UserError(f"{name}: expected a number or one value per link ({n_links}), got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise UserError(f"{name}: must be finite numbers (link {int(np.flatnonzero(~np.isfinite(arr))[0])})")
        out.append(arr)
    return tuple(out)


class ChainMailBody(Body):
    """A ChainMail object: elements `rest` (N, D), `links` (M, 2) or a built Graph, per-link limits."""

    model = "chainmail"

    def __init__(
        self,
        rest: ArrayLike,
        links: Cells | Graph,
        alpha_min: ArrayLike = _D["alpha_min"],
        alpha_max: ArrayLike = _D["alpha_max"],
        beta: ArrayLike = _D["beta"],
        *,
        relax: int = _D["relax"],
        relax_step: float = _D["relax_step"],
        order: str = _D["order"],
        depth: int = _D["depth"],
        exact: bool = _D["exact"],
        fixed: ArrayLike | None = None,
        dtype: type | np.dtype | str = _D["dtype"],
    ) -> None:
        r = np.ascontiguousarray(rest, dtype=dtype)
        if r.ndim != 2 or r.shape[1] not in (1, 2, 3):
            raise UserError(f"rest positions: expected (N, D) with D in 1..3, got shape {r.shape}")
        if not np.all(np.isfinite(r)):
            raise UserError("rest positions: coordinates must be finite numbers")
        self.rest = r
        self.positions = r.copy()
        n = len(r)
        self.graph = links if isinstance(links, Graph) else build_graph(n, links)
        self.amin, self.amax, self.beta = link_limits(self.graph.n_links, alpha_min, alpha_max, beta)
        self.fixed = np.zeros(n, dtype=np.bool_)
        if fixed is not None:
            f = np.asarray(fixed)
            if f.dtype == np.bool_ and f.shape == (n,):
                self.fixed[:] = f
            else:
                self.fixed[check_ids("fixed", f, n)] = True
        self.relax_iterations, self.relax_step = int(relax), float(relax_step)
        self.order, self.depth, self.exact = order, int(depth), bool(exact)
        self._order_cache: tuple[str | None, int] = (None, 0)
        self.workspace = make_workspace(n)
        self.held = np.zeros(0, dtype=np.int64)
        self.grab_ids = np.zeros(0, dtype=np.int64)
        self.grab_targets = np.zeros((0, r.shape[1]))
        self.moved = np.zeros(0, dtype=np.int64)
        self.last_order = np.zeros(0, dtype=np.int64)
        self.last_sponsor = np.zeros(0, dtype=np.int64)
        self.last_exact: ExactResult | None = None
        self.last_shortfall = 0.0
        self.stats = StepStats()

    def move(self, ids: ArrayLike, targets: ArrayLike, hold: bool = True) -> np.ndarray:
        """Move `ids` to `targets` from the current shape; returns the ids that changed (5.2.3-5.2.5)."""
        t0 = time.perf_counter()
        # A drag calls this every frame, often for a few hundred moved elements: the Python around the
        # kernel is kept to a few microseconds (no set operations, no O(N) pass when nothing is held).
        ids = np.atleast_1d(np.asarray(ids, dtype=np.int64))
        n = self.n
        k = len(ids)
        if k == 0 or (int(ids[0]) if k == 1 else ids.min()) < 0 or (int(ids[0]) if k == 1 else ids.max()) >= n:
            raise ValueError(f"element ids must be in 0..{n - 1}")
        d = self.rest.shape[1]
        targets = np.asarray(targets, dtype=np.float64).reshape(k, d)
        # What a tool already holds stays where it is. A drag holds only the element it moves, so the
        # usual frame needs no mask of its own: the body's anchors as they are, with no O(N) copy or
        # scan per frame (the kernel tests the anchor flag only of the few neighbours it checks).
        held = self.held
        others: np.ndarray | tuple[()]
        if len(held) == 0 or (len(held) == k == 1 and held[0] == ids[0]):
            others = ()
        else:
            others = held[~np.isin(held, ids)]
        if len(others):
            fixed = self.fixed.copy()
            fixed[others] = True
        else:
            fixed = self.fixed
        if self.exact and self.relax_iterations == 0 and self.positions.dtype == np.float64:
            # no relaxation: one exact step (the nearest shape with every link inside) instead of the
            # cascade and the exact-limit pass; the first step after construction also measures every
            # link it touches, in case the start shape was set from outside with links out of their box
            changed, res = exact_move(
                self.rest,
                self.positions,
                self.graph,
                self.amin,
                self.amax,
                self.beta,
                ids,
                targets,
                fixed,
                self.workspace,
                order=self._order_code(),
                check=not getattr(self, "_exact_clean", False),
            )
            self._exact_clean = True
            changed = changed.copy()  # a view into the workspace otherwise
            self.last_order = changed
            self.last_sponsor = np.full(len(changed), -1, dtype=np.int64)  # the step has no sponsors
            self.last_exact, self.last_shortfall = res, res.shortfall
            if hold and not (len(others) == 0 and len(held) == k == 1 and held[0] == ids[0]):
                self.held = np.union1d(self.held, ids)
            self.moved = changed
            self.stats = StepStats(1, self.last_shortfall, len(changed), time.perf_counter() - t0, {"t_cascade": 0.0})
            return changed
        order, sponsor = cascade(
            self.rest,
            self.positions,
            self.graph,
            self.amin,
            self.amax,
            self.beta,
            ids,
            targets if self.positions.dtype == np.float64 else targets.astype(self.positions.dtype),
            fixed=fixed,
            order=self._order_code(),
            workspace=self.workspace,
            depth=self.depth,
            parallel=None,  # level-parallel only where it wins (kernels.waves.parallel_wins)
        )
        self.last_order, self.last_sponsor = order, sponsor
        t_cascade = time.perf_counter() - t0
        if hold and len(others) == 0 and len(held) == k == 1 and held[0] == ids[0]:
            pass  # a drag frame: the element is already held
        elif hold:
            self.held = np.union1d(self.held, ids)
        changed = order
        if self.relax_iterations > 0 and len(order) > len(ids):
            pin = self.fixed.copy()
            pin[ids] = True
            if len(self.held):
                pin[self.held] = True
            relax_moved(self.rest, self.positions, self.graph, order, self.relax_iterations, self.relax_step, pin)
        if self.exact:
            res = exact_limits(
                self.rest,
                self.positions,
                self.graph,
                self.amin,
                self.amax,
                self.beta,
                order,
                ids,
                targets,
                fixed,
                self.workspace,
            )
            self.last_exact, self.last_shortfall = res, res.shortfall
            if len(res.changed):
                changed = np.union1d(changed, res.changed)
        self.moved = changed
        self.stats = StepStats(1, self.last_shortfall, len(changed), time.perf_counter() - t0, {"t_cascade": t_cascade})
        return changed

    def _order_code(self) -> int:
        # the name is a public attribute a pack or tool may change between moves; its code is looked up
        # once per name
        if self._order_cache[0] != self.order:
            self._order_cache = (self.order, order_code(self.order))
        return self._order_cache[1]

    # -- the body API ---------------------------------------------------------------------------
    def grab(self, ids: ArrayLike, targets: ArrayLike) -> None:
        self.move(ids, targets, hold=True)

    def release(self, ids: ArrayLike | None = None) -> None:
        if ids is None:
            self.held = np.zeros(0, dtype=np.int64)
        else:
            self.held = np.setdiff1d(self.held, np.asarray(ids, dtype=np.int64))

    def step(self, dt: float = 1.0 / 60.0) -> StepStats:
        """Nothing to integrate: a ChainMail grab has already moved the body."""
        self.moved = np.zeros(0, dtype=np.int64)
        return StepStats()

    def elastic_forces(self) -> None:
        """None: ChainMail has no force model. Its limits are geometric (5.2.6), there is no energy whose
        gradient would be a force, so `grab_force()` is None too; use XPBD or projective for forces."""
        return None

    def _cut(self, p0, p1, normal, depth) -> int:
        kw = {}
        if normal is not None:
            kw["normal"] = normal
        if depth is not None:
            kw["depth"] = depth
        return int(len(topology.cut_segment(self.positions, self.graph, p0, p1, **kw)))

    def cut(self, p0: ArrayLike, p1: ArrayLike, normal: ArrayLike | None = None, depth: float | None = None) -> int:
        return self._cut(np.asarray(p0, float), np.asarray(p1, float), normal, depth)

    def cut_path(self, points: ArrayLike, normal: ArrayLike | None = None, depth: float | None = None) -> int:
        kw = {k: v for k, v in (("normal", normal), ("depth", depth)) if v is not None}
        return int(len(topology.cut_path(self.positions, self.graph, np.asarray(points, float), **kw)))

    def add_links(self, links: Cells) -> int:
        """Join element pairs with new links carrying the first link's limits; returns how many."""
        links = np.asarray(links, dtype=np.int64).reshape(-1, 2)
        m_before = self.graph.n_links
        graph = topology.add_links(self.graph, links)
        added = graph.n_links - m_before
        if added:
            first = (self.amin[0], self.amax[0], self.beta[0]) if m_before else (_D[k] for k in PER_LINK)
            amin, amax, beta = material_arrays(added, *map(float, first))
            self.amin = np.concatenate([self.amin, amin])
            self.amax = np.concatenate([self.amax, amax])
            self.beta = np.concatenate([self.beta, beta])
            self.graph = graph
            self.workspace.ensure(graph.indices.shape[0] + 1)
        return added

    def reset(self) -> None:
        """Rest shape, every link alive, nothing held."""
        self.positions[:] = self.rest
        self.graph.revive()
        self.held = np.zeros(0, dtype=np.int64)

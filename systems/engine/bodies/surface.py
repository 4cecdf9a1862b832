"""SurfaceChainMail through the body API (thesis 4.4-4.5): a sheet deformed as the thesis's cutting trainer
deformed its layers.

The sheet is parametrised by its best-fit plane: (u, v) in the plane, a scalar offset along its normal.
A grab is split in two as in 4.4: the tangential part moves the element in the (u, v) plane with
Generalised ChainMail on the mesh's links (the 2-D ChainMailBody, its limits, relaxation and exact pass),
the normal part moves the offset and is passed on to neighbours that differ from it by more than
`beta` times their rest separation (4.4.2). Both parts are combined back into 3-D positions (4.4.3).

The normal part here is exact: instead of the thesis's breadth-first cascade, in which an element moved
for one sponsor is not revisited for another, each element's offset is clamped into the band that the
grabbed elements' targets allow at its graph distance (a Dijkstra pass from the grabbed elements, which
stops where nothing changes), so every live link stays within its normal limit after every move.
Cuts kill links of the shared graph (chainsim.systems.engine.kernels.topology), which both parts read.
"""

from __future__ import annotations

import heapq
import time

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.bodies.base import Body, Cells, StepStats, check_positions
from chainsim.systems.engine.bodies.chainmail import ChainMailBody
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels import topology
from chainsim.systems.engine.kernels.graph import build_graph
from chainsim.systems.engine.model_params import defaults


@njit(cache=True)
def bound_from(indptr, indices, link, alive, lim, sources, values):
    """For every element v, min over k of values[k] + dist(sources[k], v), the shortest distance over
    live links weighted by `lim` (inf where no source reaches): one multi-source pass, whatever the
    number of sources."""
    n = indptr.shape[0] - 1
    best = np.full(n, np.inf)
    heap = [(0.0, 0)]
    heap.pop()
    for k in range(sources.shape[0]):
        s = sources[k]
        if values[k] < best[s]:
            best[s] = values[k]
            heapq.heappush(heap, (values[k], s))
    while len(heap):
        bv, e = heapq.heappop(heap)
        if bv > best[e]:
            continue
        for j in range(indptr[e], indptr[e + 1]):
            if not alive[link[j]]:
                continue
            f = indices[j]
            nb = bv + lim[link[j]]
            if nb < best[f]:
                best[f] = nb
                heapq.heappush(heap, (nb, f))
    return best


@njit(cache=True)
def clamp_pass(disp, indptr, indices, link, alive, lim, sources, values, pinned, sign):
    """One side of the normal band: with sign = 1, disp[e] = min(disp[e], min_k values[k] + dist(k, e));
    with sign = -1 the lower side. Sources take their value. The pass walks outward only from elements it
    changed: where disp already satisfied every link, an unchanged element bounds its neighbours as the
    band would. Returns a mask of the changed elements."""
    n = disp.shape[0]
    best = np.full(n, np.inf)
    changed = np.zeros(n, dtype=np.bool_)
    heap = [(0.0, 0)]
    heap.pop()
    for k in range(sources.shape[0]):
        s = sources[k]
        v = sign * values[k]
        if v < best[s]:
            best[s] = v
            heapq.heappush(heap, (v, s))
    is_source = np.zeros(n, dtype=np.bool_)
    is_source[sources] = True
    while len(heap):
        bv, e = heapq.heappop(heap)
        if bv > best[e]:
            continue
        cur = sign * disp[e]
        if is_source[e]:
            if cur != bv:
                disp[e] = sign * bv
                changed[e] = True
        elif cur > bv:
            disp[e] = sign * bv
            changed[e] = True
        else:
            continue  # unchanged: its neighbours are within their links of it already
        for j in range(indptr[e], indptr[e + 1]):
            if not alive[link[j]]:
                continue
            f = indices[j]
            if pinned[f]:
                continue
            nb = bv + lim[link[j]]
            if nb < best[f]:
                best[f] = nb
                heapq.heappush(heap, (nb, f))
    return changed


#: the body's defaults, from the one declaration of its parameters
_D = defaults("surface")


class SurfaceChainMailBody(Body):
    """A sheet of `triangles` over `rest` (N, 3) under SurfaceChainMail (thesis 4.4): in-plane limits
    alpha_min..alpha_max and shear beta, normal offsets limited to beta times the rest separation."""

    model = "surface"

    def __init__(
        self,
        rest: ArrayLike,
        triangles: Cells,
        alpha_min: ArrayLike = _D["alpha_min"],
        alpha_max: ArrayLike = _D["alpha_max"],
        beta: ArrayLike = _D["beta"],
        *,
        relax: int = _D["relax"],
        exact: bool = _D["exact"],
        order: str = _D["order"],
        fixed: ArrayLike | None = None,
    ) -> None:
        super().__init__(rest, fixed)
        tris = np.asarray(triangles, dtype=np.int64)
        if tris.ndim != 2 or tris.shape[1] != 3 or len(tris) == 0:
            raise UserError("a surface ChainMail body needs triangles (K, 3)")
        self.graph = build_graph(self.n, meshgen.links_from_cells(tris))
        # the best-fit plane: (u, v) along its two widest directions, the offset along its normal
        self.origin = self.rest.mean(axis=0)
        _, _, vt = np.linalg.svd(self.rest - self.origin, full_matrices=False)
        self.axes, self.normal = vt[:2].copy(), vt[2].copy()
        rel = self.rest - self.origin
        self.uv_rest = np.ascontiguousarray(rel @ self.axes.T)
        self.h_rest = rel @ self.normal
        self.disp = np.zeros(self.n)  # normal offset from rest
        self.plane = ChainMailBody(
            self.uv_rest,
            self.graph,
            alpha_min,
            alpha_max,
            beta,
            relax=relax,
            exact=exact,
            order=order,
            fixed=self.fixed,
        )
        links = self.graph.links
        # beta per link, as the plane's ChainMail holds it (a number or one value per link of the graph)
        self.normal_limit = self.plane.beta * np.linalg.norm(
            self.uv_rest[links[:, 1]] - self.uv_rest[links[:, 0]], axis=1
        )
        self._applied = (np.zeros(0, dtype=np.int64), np.zeros((0, 3)))

    # -- the two parts of a move ------------------------------------------------------------------
    def _normal_move(self, ids: np.ndarray, targets: np.ndarray) -> None:
        g = self.graph
        pinned = self.fixed.copy()
        held = self.plane.held[~np.isin(self.plane.held, ids)]
        pinned[held] = True
        # what the pinned elements allow each grabbed one at its distance from them (4.4.2's limit): the
        # band max_p(disp_p - dist) .. min_p(disp_p + dist), both sides in one pass over the sheet each
        # (one element grabbed, as a tool holds one: one pass from it instead)
        graph = (g.indptr, g.indices, g.link, g.alive, self.normal_limit)
        if len(ids) == 1:
            dist = bound_from(*graph, ids, np.zeros(1))
            near = pinned & np.isfinite(dist)
            if near.any():
                lo1 = np.max(self.disp[near] - dist[near])
                hi1 = np.min(self.disp[near] + dist[near])
                targets = np.minimum(np.maximum(targets, lo1), hi1)
        else:
            src = np.flatnonzero(pinned)
            hi = bound_from(*graph, src, self.disp[src])[ids]
            lo = -bound_from(*graph, src, -self.disp[src])[ids]
            targets = np.minimum(np.maximum(targets, lo), hi)
        pinned[ids] = False
        args = (g.indptr, g.indices, g.link, g.alive, self.normal_limit, ids, targets, pinned)
        clamp_pass(self.disp, *args, 1.0)
        clamp_pass(self.disp, *args, -1.0)

    def _apply(self, ids: np.ndarray, targets: np.ndarray) -> None:
        rel = targets - self.origin
        self.plane.move(ids, rel @ self.axes.T, hold=True)
        self._normal_move(ids, rel @ self.normal - self.h_rest[ids])
        new = self.origin + self.plane.positions @ self.axes + (self.h_rest + self.disp)[:, None] * self.normal
        # an element neither part moved (a fixed one, or one the move never reached) is exactly at rest,
        # not at its rest shape passed through the plane and back (round-off would move fixed elements
        # and mark the whole sheet as moved every frame)
        same = np.all(self.plane.positions == self.uv_rest, axis=1) & (self.disp == 0.0)
        new[same] = self.rest[same]
        self.positions[:] = new

    # -- the body API ---------------------------------------------------------------------------------
    def _grab_changed(self) -> None:
        self.plane.held = self.grab_ids.copy()

    def _solve(self, dt: float) -> StepStats:
        t0 = time.perf_counter()
        ids, targets = self.grab_ids, self.grab_targets
        last_ids, last_t = self._applied
        if len(ids) and not (np.array_equal(ids, last_ids) and np.array_equal(targets, last_t)):
            self._apply(ids, targets)
            self._applied = (ids.copy(), targets.copy())
        return StepStats(1 if len(ids) else 0, 0.0, 0, time.perf_counter() - t0)

    def _cut(self, p0, p1, normal, depth) -> int:
        kw = {k: v for k, v in (("normal", normal), ("depth", depth)) if v is not None}
        return int(len(topology.cut_segment(self.positions, self.graph, p0, p1, **kw)))

    def cut_path(self, points: ArrayLike, normal: ArrayLike | None = None, depth: float | None = None) -> int:
        kw = {k: v for k, v in (("normal", normal), ("depth", depth)) if v is not None}
        pts = check_positions("cut path", points)
        return int(len(topology.cut_path(self.positions, self.graph, pts, **kw)))

    def link_excess(self) -> tuple[float, float]:
        """How far (mesh units) the worst live link lies outside its in-plane box and its normal limit."""
        alive = self.graph.alive
        links = self.graph.links[alive]
        dn = np.abs(self.disp[links[:, 1]] - self.disp[links[:, 0]]) - self.normal_limit[alive]
        r = self.uv_rest[links[:, 1]] - self.uv_rest[links[:, 0]]
        p = self.plane.positions[links[:, 1]] - self.plane.positions[links[:, 0]]
        amin, amax, beta = self.plane.amin[alive], self.plane.amax[alive], self.plane.beta[alive]
        worst = np.zeros(len(links))
        for a in range(2):
            other = np.abs(r).sum(axis=1) - np.abs(r[:, a])
            lo = np.where(r[:, a] >= 0, amin * r[:, a], amax * r[:, a]) - beta * other
            hi = np.where(r[:, a] >= 0, amax * r[:, a], amin * r[:, a]) + beta * other
            worst = np.maximum(worst, np.maximum(lo - p[:, a], p[:, a] - hi))
        return float(max(worst.max(initial=0.0), 0.0)), float(max(dn.max(initial=0.0), 0.0))

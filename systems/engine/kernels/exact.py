"""Exact-limit pass after a ChainMail cascade: every link of the moved region back inside its box.

What the cascade guarantees (5.2.3-5.2.4): an element that moves is put inside its box against the
sponsor that moved it. 5.2.4 then shows that two elements B, C moved by a common sponsor A satisfy a
WIDENED box for the link B-C (the link's limits plus the freedom B had inside its own box), which is
what lets the cascade visit each element once; it does not show that C lies in the link's own box, and
links between elements moved by different sponsors, or between a moved element and a fixed one, are
not covered at all. On a face pulled a few centimetres a tenth of the links can end up outside their
boxes, some by several rest lengths.

This pass removes that. The limits of 5.2.2 are, axis by axis, difference constraints on the link
vector u = x_B - x_A:  lo_a <= u_a <= hi_a, with lo, hi fixed by the rest offset and the material. The
axes are independent, and per axis every violated constraint can be fixed by LOWERING one end (the
upper one) or by RAISING the other. With the pinned elements P (fixed, held and grabbed) kept in place:

    walk 1  moves elements on each axis only in the direction of the pull (lagging elements follow the
            tool), each as little as it must, until every link that such moves can fix holds: a
            label-correcting shortest-path walk (FIFO) that gives the greatest such configuration on
            the lowering side, the least on the raising side;
    walk 2  the same in the opposite direction, from the links walk 1 changed or could not fix
            (those that needed a pin to move).

If the pins are consistent (some configuration satisfies every link with them in place), walk 2 ends
with every link inside its box and no pin moved: per axis the feasible set is a lattice, and walk 2
computes the least feasible point above walk 1's result, which lies below the greatest feasible point.
Elements that no violation reaches stay exactly where the cascade put them; the walks start from the
cascade's moved elements and spread only as far as a correction needs.

If walk 2 finds a link it could only fix by moving a pin, a grabbed element was asked to go further
than the limits allow from the fixed ones. Its reachable set is a box (per axis [L, U] with
L = max over pins p of c_p - dist(g -> p), U = min over pins of c_p + dist(p -> g): shortest paths over
the links' slack, found with Dijkstra and stopped as soon as no further pin can matter), so the
reachable position nearest its target is the per-axis clamp of the target. The grabbed element is put
there and both walks run again from the cascade's result. Several grabbed elements are settled in the
order given, each against the fixed ones and those settled before it; `shortfall` says how far the
furthest stopped from its target. A drag repeats such pulls with the same fixed elements, so when a
second one needs the search, the boxes of every element against the fixed ones are computed at once (one
multi-source walk from the fixed elements over the whole mesh) and later pulls read the first grabbed
element's box from there, as long as the graph, its cut links, the material, the fixed mask and the fixed
elements' positions are the ones it was computed for.

The exact step (exact_move) is the other way round: no cascade, and the start shape's links all hold
(the rest shape, or what an exact step left). Per axis a, with the grabbed element moved by s = sign of
its move (+1 up), the nearest shape is the least closure of the start shape x0 in direction s with the
grabbed element at its target t: y_v = max_s(x0_v, t - dist(g -> v)), dist the shortest path over the
links' slack (the reduced weights of 5.2.2's difference constraints, >= 0 since amin <= 1 <= amax).
Any shape with every link inside and g at t has y_v >= t - dist(g -> v) on that side, so each element
moves no further on any axis than in any other such shape: the closure is the nearest reachable shape.
It is also cheap: an element with t - dist(g -> v) <= x0_v stops the walk, since the start shape's
links already carry the bound beyond it, so one label-correcting walk from the grabbed element over all
axes at once visits only what moves (about once each: on the benchmark pulls 1.0-1.3 visits per changed
element) and checks each of their links from the moving end. A fixed element the walk would push says
the target is out of reach on that axis by the largest such push E_a: the grabbed element's reachable
bound is t - E_a (a shortest path to the fixed element that binds hardest), and every label the walk set
moves back by E_a, to no less than x0 (the closure of the clamped target, without a second walk). With
several grabbed elements the walk starts from all of them; when they pull one axis both ways or stop
one another, the step settles them as exact_limits does (cascade, then the walks).

Deterministic and single-threaded. Work is counted in element visits and capped (`max_visits`), so a
degenerate input cannot hang it; the result then says it is incomplete and gives the residual left.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .chainmail import cascade
from .graph import Graph, fixed_mask
from .prefetch import prefetch

#: relative tolerance of a link check: inside when within this fraction of the link's L1 rest offset of
#: its box; keeps rounding from re-queueing elements around cycles of links with no slack (rigid)
EPS_REL = 1e-10
#: rounding of a stored coordinate, as a fraction of the coordinates' magnitude, added to that tolerance
_ROUND = {np.dtype(np.float64): 4 * np.finfo(np.float64).eps, np.dtype(np.float32): 4 * np.finfo(np.float32).eps}
#: in the reported figures a link is outside when its distance to the box exceeds this fraction of its
#: rest length (float32 positions cannot be placed closer than their own rounding)
TOL = {np.dtype(np.float64): 1e-9, np.dtype(np.float32): 1e-5}

#: the exact step's walk asks for the rows of the element it serves this many visits ahead
_AHEAD = 8

_ERRORS = {
    -1: "grabbed ids must be element ids in [0, N)",
    -2: "moved ids must be element ids in [0, N)",
    -3: "targets must be finite (no NaN or inf)",
}


class ExactResult(NamedTuple):
    """What the exact-limit pass did.

    changed:   ids the pass moved (after the cascade's moves), each once, int64
    residual:  worst distance of a checked link from its box, as a fraction of its rest length
    outside:   checked links still outside by more than TOL of their rest length (0 unless capped or
               the fixed elements themselves break the limits)
    checked:   links checked at the end (those touching an element the pass moved or could not fix)
    shortfall: largest distance between a grabbed element's target and where it ended (0: all reached)
    visits:    element visits the walks and searches made (the pass's work)
    complete:  False when max_visits stopped a walk early
    """

    changed: np.ndarray
    residual: float
    outside: int
    checked: int
    shortfall: float
    visits: int
    complete: bool


class ExactWorkspace:
    """Scratch of the exact pass for one mesh, reused across calls. Flags are generation stamps, so
    nothing of size N is cleared per call."""

    def __init__(self, n: int, dim: int):
        self.n = n
        self.dim = dim
        # pin (== gen: a grabbed element pinned in this call), region (== +-gen: in the region whose links
        # are checked), log_stamp (== lgen: position saved in the log), as rows of one array
        self.stamps = np.zeros((3, n), dtype=np.int32)
        self.pin, self.region, self.log_stamp = self.stamps
        # the log and the queue have a row to spare: the exact step writes an entry before counting it
        self.log_ids = np.empty(n + 1, dtype=np.int64)
        self.x0 = np.empty((n + 1, dim), dtype=np.float64)  # positions before the pass changed them
        self.flag = np.zeros(n, dtype=np.int32)  # == lgen: end of a link a walk could not fix
        self.flag_ids = np.empty(n, dtype=np.int64)
        self.queue = np.empty(n + 1, dtype=np.int64)
        self.inq = np.zeros(n, dtype=np.bool_)  # all False between walks
        self.dist = np.empty((n, 2 * dim), dtype=np.float64)  # reach labels, per axis and side
        self.dstamp = np.zeros(n, dtype=np.int32)
        self.result = np.zeros(9, dtype=np.float64)
        self.gen = 0  # each call uses gen and gen + 1 (a second attempt)
        self.dgen = 0
        # the reachable boxes against the fixed elements (_pin_field), built once a pull out of reach
        # repeats with the same graph, material and fixed elements (a drag), then read instead of searched
        self.field = np.empty((0, 2 * dim), dtype=np.float64)
        self.field_key: tuple = ()
        self.field_fixed = np.zeros(0, dtype=np.bool_)
        self.field_ids = np.zeros(0, dtype=np.int64)
        self.field_pos = np.zeros((0, dim), dtype=np.float64)
        self.field_seen: tuple = ()
        # what the exact step reads of a graph: (graph, version, kernel arguments with the CSR in int32
        # where it fits, whether any link is cut), kept while the graph, its link state and material stay
        self.step_key: tuple = ()

    def step_args(self, graph, workspace) -> tuple:
        """(kernel arguments, some link cut) of `graph` for the exact step, made once per graph state."""
        k = self.step_key
        same = k and k[0] is graph and k[1] == graph.version and k[2] is graph.entry_amin
        if not (same and k[3] is graph.entry_beta):
            kargs = graph.kernel_args
            if workspace is not None and hasattr(workspace, "narrow_csr"):
                kargs = workspace.narrow_csr(graph, kargs)
            k = self.step_key = (graph, graph.version, graph.entry_amin, graph.entry_beta, kargs, not graph.alive.all())
        return k[4], k[5]

    def field_args(self, graph) -> tuple:
        """(field, valid for this graph and material, fixed mask, fixed ids, their positions) for _exact;
        the kernel checks the mask and positions."""
        ok = _same_key(self.field_key, _field_key(graph))
        return self.field, ok, self.field_fixed, self.field_ids, self.field_pos

    def searched(self, rest, pos, graph, fixed) -> None:
        """A pull was settled by searching: build the field when the previous such call had the same key."""
        key = _field_key(graph)
        again = _same_key(self.field_seen, key)
        self.field_seen = key
        if not again:
            return
        n = pos.shape[0]
        if self.field.shape[0] != n:
            self.field = np.empty((n, 2 * self.dim), dtype=np.float64)
        _pin_field(rest, pos, *graph.kernel_args, fixed, self.field, self.queue, self.inq)
        self.field_fixed = fixed.copy()
        self.field_ids = np.flatnonzero(fixed).astype(np.int64)
        self.field_pos = np.ascontiguousarray(pos[self.field_ids], dtype=np.float64)
        self.field_key = key
        self.field_seen = ()

    def next_generation(self) -> int:
        if self.gen >= 2**31 - 8 or self.dgen >= 2**30:
            for a in (self.pin, self.region, self.log_stamp, self.flag, self.dstamp):
                a[:] = 0
            self.gen = 0
            self.dgen = 0
        self.gen += 2
        return self.gen


def _field_key(graph) -> tuple:
    """What the pin field depends on besides the fixed elements: the graph, its link state, the material."""
    return (graph, graph.version, graph.entry_amin, graph.entry_amax, graph.entry_beta)


def _same_key(a: tuple, b: tuple) -> bool:
    return len(a) == len(b) == 5 and a[1] == b[1] and all(x is y for x, y in zip(a[:1] + a[2:], b[:1] + b[2:]))


def exact_workspace(workspace, n: int, dim: int) -> ExactWorkspace:
    """The ExactWorkspace kept on a cascade Workspace (made on first use), or a temporary one."""
    ex = getattr(workspace, "exact", None) if workspace is not None else None
    if ex is None or ex.n != n or ex.dim != dim:
        ex = ExactWorkspace(n, dim)
        if workspace is not None:
            workspace.exact = ex
    return ex


# ----------------------------------------------------------------------------------------------------
# kernels


@njit(cache=True)
def _excess(u, d, l1, amin_l, amax_l, beta_l):
    """How far u = x_e - x_s lies outside its interval on one axis (<= 0 inside), and its signed offset
    from the interval's centre (> 0: above), for rest offset d = r_e - r_s and L1 rest length l1 (5.2.2,
    5.2.6).

    The interval of 5.2.2, [amin|d| - beta o, amax|d| + beta o] mirrored when d < 0, is centred on
    d (amin + amax) / 2 with half-width |d| (amax - amin) / 2 + beta o whatever the sign of d: no branch.
    """
    ad = abs(d)
    e = u - 0.5 * (amin_l + amax_l) * d
    return abs(e) - (0.5 * (amax_l - amin_l) * ad + beta_l * (l1 - ad)), e


@njit(cache=True)
def _greater(a, b):
    # the builtin max on floats is slower here; a plain comparison (off the hot loops: a call costs)
    return a if a > b else b


@njit(cache=True)
def _log(i, pos, log_stamp, lgen, log_ids, x0, nlog):
    """Save i's position the first time the pass moves it; returns the new log length."""
    if log_stamp[i] != lgen:
        log_stamp[i] = lgen
        log_ids[nlog] = i
        for a in range(pos.shape[1]):
            x0[nlog, a] = pos[i, a]
        return nlog + 1
    return nlog


@njit(cache=True)
def _walk(
    rest,
    pos,
    indptr,
    indices,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    fixed,
    has_fixed,
    pin,
    gen,
    down,
    seeds,
    n_seeds,
    seeds2,
    n_seeds2,
    log_ids,
    nlog,
    log_stamp,
    lgen,
    x0,
    flag_ids,
    nflag,
    flag,
    queue,
    inq,
    eps_rel,
    eps_abs,
    max_visits,
):
    """One monotone walk: on axis a elements move only down (down[a]) or only up, each as little as a
    violated link needs, until every link that such moves can fix holds. Moved elements are logged
    (log_ids, x0: the position before); both ends of a link that needed a pin to move are flagged.
    Starts from seeds[:n_seeds] and seeds2[:n_seeds2]. Returns (visits, blocked, blocked by a fixed element,
    nlog, nflag, finished).
    """
    n = pos.shape[0]
    dim = pos.shape[1]
    head = 0
    tail = 0
    size = 0
    for k in range(n_seeds + n_seeds2):
        i = seeds[k] if k < n_seeds else seeds2[k - n_seeds]
        if not inq[i]:
            inq[i] = True
            queue[tail] = i
            tail += 1
            if tail == n:
                tail = 0
            size += 1
    visits = 0
    blocked = 0
    at_fixed = 0
    while size > 0 and visits < max_visits:
        i = queue[head]
        head += 1
        if head == n:
            head = 0
        size -= 1
        inq[i] = False
        visits += 1
        again = False
        if dim == 3:
            # i's rows and a uniform material loaded once per visit (stores to pos keep the compiler from
            # hoisting them itself); p0..p2 follow i when a correction moves it
            ri0 = np.float64(rest[i, 0])
            ri1 = np.float64(rest[i, 1])
            ri2 = np.float64(rest[i, 2])
            p0 = np.float64(pos[i, 0])
            p1 = np.float64(pos[i, 1])
            p2 = np.float64(pos[i, 2])
            mid = 0.5 * (eamin[0] + eamax[0])
            half = 0.5 * (eamax[0] - eamin[0])
            bt = ebeta[0]
        for jj in range(indptr[i], indptr[i + 1]):
            if not ealive[jj]:
                continue
            j = indices[jj]
            if dim == 3:
                # unrolled: the common case, a link inside its box, costs a few multiply-adds
                d0 = np.float64(rest[j, 0]) - ri0
                d1 = np.float64(rest[j, 1]) - ri1
                d2 = np.float64(rest[j, 2]) - ri2
                a0 = abs(d0)
                a1 = abs(d1)
                a2 = abs(d2)
                l1 = a0 + a1 + a2
                eps = eps_rel * l1 + eps_abs
                if ms != 0:
                    mid = 0.5 * (eamin[jj] + eamax[jj])
                    half = 0.5 * (eamax[jj] - eamin[jj])
                    bt = ebeta[jj]
                # signed offset from the centre of the interval, and distance beyond its half-width
                s0 = np.float64(pos[j, 0]) - p0 - mid * d0
                s1 = np.float64(pos[j, 1]) - p1 - mid * d1
                s2 = np.float64(pos[j, 2]) - p2 - mid * d2
                e0 = abs(s0) - (half * a0 + bt * (l1 - a0))
                e1 = abs(s1) - (half * a1 + bt * (l1 - a1))
                e2 = abs(s2) - (half * a2 + bt * (l1 - a2))
                if e0 <= eps and e1 <= eps and e2 <= eps:
                    continue
            else:
                l1 = 0.0
                for a in range(dim):
                    l1 += abs(np.float64(rest[j, a]) - np.float64(rest[i, a]))
                eps = eps_rel * l1 + eps_abs
                e0 = e1 = e2 = s0 = s1 = s2 = 0.0
            for a in range(dim):
                if dim == 3:  # the axes are independent: a move on one leaves the others' values valid
                    ex = e0 if a == 0 else (e1 if a == 1 else e2)
                    sd = s0 if a == 0 else (s1 if a == 1 else s2)
                else:
                    d = np.float64(rest[j, a]) - np.float64(rest[i, a])
                    ex, sd = _excess(
                        np.float64(pos[j, a]) - np.float64(pos[i, a]),
                        d,
                        l1,
                        eamin[jj * ms],
                        eamax[jj * ms],
                        ebeta[jj * ms],
                    )
                if ex <= eps:
                    continue
                # u above its interval (sd > 0): lower j or raise i; below: lower i or raise j
                if sd > 0.0:
                    mover = j if down[a] else i
                else:
                    mover = i if down[a] else j
                # (written out: a call passing arrays costs more than the work here)
                if (has_fixed and fixed[mover]) or pin[mover] == gen:
                    blocked += 1
                    if has_fixed and fixed[mover]:
                        at_fixed += 1
                    if flag[i] != lgen:
                        flag[i] = lgen
                        flag_ids[nflag] = i
                        nflag += 1
                    if flag[j] != lgen:
                        flag[j] = lgen
                        flag_ids[nflag] = j
                        nflag += 1
                    continue
                if log_stamp[mover] != lgen:  # first move in this pass: save where it was
                    log_stamp[mover] = lgen
                    log_ids[nlog] = mover
                    for b in range(dim):
                        x0[nlog, b] = pos[mover, b]
                    nlog += 1
                pos[mover, a] = np.float64(pos[mover, a]) + (-ex if down[a] else ex)
                if mover == i:
                    again = True
                    if dim == 3:
                        p0 = np.float64(pos[i, 0])
                        p1 = np.float64(pos[i, 1])
                        p2 = np.float64(pos[i, 2])
                elif not inq[j]:
                    inq[j] = True
                    queue[tail] = j
                    tail += 1
                    if tail == n:
                        tail = 0
                    size += 1
        if again and not inq[i]:
            # i moved while its links were being checked: the ones checked before the move look again
            inq[i] = True
            queue[tail] = i
            tail += 1
            if tail == n:
                tail = 0
            size += 1
    finished = size == 0
    while size > 0:  # leave the queue flags clean for the next walk
        inq[queue[head]] = False
        head += 1
        if head == n:
            head = 0
        size -= 1
    return visits, blocked, at_fixed, nlog, nflag, finished


@njit(cache=True)
def _reach(
    rest,
    pos,
    indptr,
    indices,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    fixed,
    has_fixed,
    pin,
    gen,
    g,
    limit,
    zb,
    best,
    dist,
    dstamp,
    dgen,
    queue,
    inq,
):
    """How far element g may move from its rest position, per axis and side, with the pins in place.

    Side s = 2 a (up along axis a) gives best[s] = min over pins p of z_p + dist_a(p -> g); side 2 a + 1
    (down) gives min over pins of dist_a(g -> p) - z_p, where z is a pin's displacement from rest and
    dist_a the shortest path over the links' slack on axis a: how far the link's bound lets its far end
    go beyond where the rest offset puts it, >= 0 (the reduced weights of the difference constraints).
    A side is searched only while a path can still beat limit[s] (the displacement asked for) and the
    best found, given zb[s] (the smallest z, up, or minus the largest, down, over all pins); all sides
    share one label-correcting walk. best[s] stays +inf when no pin binds. Returns the visits.
    """
    n = pos.shape[0]
    dim = pos.shape[1]
    ns = 2 * dim
    # a side can bind only if the displacement asked for exceeds the smallest a pin could allow
    act = np.empty(ns, dtype=np.int64)
    nact = 0
    for k in range(ns):
        best[k] = np.inf
        dist[g, k] = 0.0
        if limit[k] > zb[k]:
            act[nact] = k
            nact += 1
    if nact == 0:
        return 0
    dstamp[g] = dgen
    head = 0
    tail = 1
    size = 1
    queue[0] = g
    inq[g] = True
    visits = 0
    dv = np.empty(3)
    while size > 0:
        v = queue[head]
        head += 1
        if head == n:
            head = 0
        size -= 1
        inq[v] = False
        visits += 1
        if v != g and ((has_fixed and fixed[v]) or pin[v] == gen):
            for q in range(nact):
                k = act[q]
                z = np.float64(pos[v, k // 2]) - np.float64(rest[v, k // 2])
                c = dist[v, k] + z if k % 2 == 0 else dist[v, k] - z
                if c < best[k]:
                    best[k] = c
            continue
        for jj in range(indptr[v], indptr[v + 1]):
            if not ealive[jj]:
                continue
            u = indices[jj]
            l1 = 0.0
            for b in range(dim):
                dv[b] = np.float64(rest[v, b]) - np.float64(rest[u, b])
                l1 += abs(dv[b])
            # slack of the link on axis a, up: as u -> v, a bound on x_v - x_u (its rest offset dv[a]);
            # down: as v -> u (offset -dv[a]). With m, h the centre and half-width factors of _excess,
            # bound - offset = (m - 1) offset + h |offset| + beta o, >= 0 since amin <= 1 <= amax.
            mid1 = 0.5 * (eamin[jj * ms] + eamax[jj * ms]) - 1.0
            half = 0.5 * (eamax[jj * ms] - eamin[jj * ms])
            improved = False
            for q in range(nact):
                k = act[q]
                d = dv[k // 2] if k % 2 == 0 else -dv[k // 2]
                ad = abs(d)
                w = mid1 * d + half * ad + ebeta[jj * ms] * (l1 - ad)
                nd = dist[v, k] + (w if w > 0.0 else 0.0)
                if nd + zb[k] >= best[k] or nd + zb[k] >= limit[k]:
                    continue  # no pin beyond this can bind on this side
                if dstamp[u] != dgen:
                    dstamp[u] = dgen
                    for kk in range(ns):
                        dist[u, kk] = np.inf
                if nd < dist[u, k]:
                    dist[u, k] = nd
                    improved = True
            if improved and not inq[u]:
                inq[u] = True
                queue[tail] = u
                tail += 1
                if tail == n:
                    tail = 0
                size += 1
    return visits


@njit(cache=True)
def _pin_field(rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, fixed, field, queue, inq):
    """The reachable boxes of every element against the fixed ones, at once: field[v, 2 a] = min over
    fixed p of z_p + dist_a(p -> v) and field[v, 2 a + 1] = min over p of dist_a(v -> p) - z_p, with z
    and dist_a as in _reach (+inf where no fixed element binds). A multi-source label-correcting walk
    from the fixed elements, whose labels stay their own (a path does not pass through one, as in
    _reach). Returns the visits."""
    n = pos.shape[0]
    dim = pos.shape[1]
    ns = 2 * dim
    head = 0
    tail = 0
    size = 0
    for v in range(n):
        if fixed[v]:
            for a in range(dim):
                z = np.float64(pos[v, a]) - np.float64(rest[v, a])
                field[v, 2 * a] = z
                field[v, 2 * a + 1] = -z
            inq[v] = True
            queue[tail] = v
            tail += 1
            size += 1
        else:
            for k in range(ns):
                field[v, k] = np.inf
    if tail == n:
        tail = 0
    visits = 0
    while size > 0:
        u = queue[head]
        head += 1
        if head == n:
            head = 0
        size -= 1
        inq[u] = False
        visits += 1
        for jj in range(indptr[u], indptr[u + 1]):
            v = indices[jj]
            if not ealive[jj] or fixed[v]:
                continue
            l1 = 0.0
            for b in range(dim):
                l1 += abs(np.float64(rest[v, b]) - np.float64(rest[u, b]))
            mid1 = 0.5 * (eamin[jj * ms] + eamax[jj * ms]) - 1.0
            half = 0.5 * (eamax[jj * ms] - eamin[jj * ms])
            be = ebeta[jj * ms]
            improved = False
            for k in range(ns):
                if field[u, k] == np.inf:
                    continue
                # the weight _reach gives the step v -> u, met here in the other direction
                dv = np.float64(rest[v, k // 2]) - np.float64(rest[u, k // 2])
                d = dv if k % 2 == 0 else -dv
                ad = abs(d)
                w = mid1 * d + half * ad + be * (l1 - ad)
                nd = field[u, k] + (w if w > 0.0 else 0.0)
                if nd < field[v, k]:
                    field[v, k] = nd
                    improved = True
            if improved and not inq[v]:
                inq[v] = True
                queue[tail] = v
                tail += 1
                if tail == n:
                    tail = 0
                size += 1
    return visits


@njit(cache=True)
def _settle_targets(
    rest,
    pos,
    indptr,
    indices,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    fixed,
    has_fixed,
    pin,
    gen,
    grabbed,
    targets,
    dist,
    dstamp,
    dgen,
    queue,
    inq,
    field,
    use_field,
    result,
):
    """Put each grabbed element at the reachable position nearest its target (the per-axis clamp of the
    target into its reachable box), in the order given, each pinned before the next is settled (pin
    must hold no grabbed element on entry). The first one is settled against the fixed elements alone:
    its box is read from `field` when use_field (see _pin_field), and result[8] is set when it had to be
    searched instead. Returns (visits, dgen, moved: whether any was clamped)."""
    n = pos.shape[0]
    dim = pos.shape[1]
    ns = 2 * dim
    limit = np.empty(ns)
    zb = np.empty(ns)
    best = np.empty(ns)
    visits = 0
    clamped = False
    first = True
    for k in range(grabbed.shape[0]):
        g = grabbed[k]
        if has_fixed and fixed[g]:
            continue
        if first and has_fixed:
            first = False
            if use_field:
                for a in range(dim):
                    r = np.float64(rest[g, a])
                    x = np.float64(targets[k, a])
                    if field[g, 2 * a] < x - r:
                        x = r + field[g, 2 * a]
                    if field[g, 2 * a + 1] < r - x:
                        x = r - field[g, 2 * a + 1]
                    if x != pos[g, a]:
                        clamped = True
                    pos[g, a] = x
                pin[g] = gen
                continue
            result[8] = 1.0
        first = False
        for s in range(ns):
            zb[s] = np.inf
        any_pin = False
        for i in range(n):
            if i != g and ((has_fixed and fixed[i]) or pin[i] == gen):
                any_pin = True
                for a in range(dim):
                    z = np.float64(pos[i, a]) - np.float64(rest[i, a])
                    if z < zb[2 * a]:
                        zb[2 * a] = z
                    if -z < zb[2 * a + 1]:
                        zb[2 * a + 1] = -z
        if any_pin:
            for a in range(dim):
                r = np.float64(rest[g, a])
                limit[2 * a] = np.float64(targets[k, a]) - r
                limit[2 * a + 1] = r - np.float64(targets[k, a])
            dgen += 1
            visits += _reach(
                rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, fixed, has_fixed, pin, gen, g, limit,
                zb, best, dist, dstamp, dgen, queue, inq,
            )  # fmt: skip
            for a in range(dim):
                r = np.float64(rest[g, a])
                x = np.float64(targets[k, a])
                if best[2 * a] < x - r:
                    x = r + best[2 * a]
                if best[2 * a + 1] < r - x:
                    x = r - best[2 * a + 1]
                if x != pos[g, a]:
                    clamped = True
                pos[g, a] = x
        pin[g] = gen
    return visits, dgen, clamped


@njit(cache=True)
def _restore(pos, log_ids, x0, nlog):
    for k in range(nlog):
        i = log_ids[k]
        for a in range(pos.shape[1]):
            pos[i, a] = x0[k, a]


@njit(cache=True)
def _residual(rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, seeds, n1, seeds2, n2, region, rgen, tol):
    """Worst distance outside the box over the live links touching seeds[:n1] and seeds2[:n2], relative
    to rest length; also how many are outside by more than tol and how many were checked (each once)."""
    # region[i] == rgen: in the region, links not yet counted; == -rgen: in the region, counted
    dim = pos.shape[1]
    for k in range(n1 + n2):
        i = seeds[k] if k < n1 else seeds2[k - n1]
        region[i] = rgen
    worst = 0.0
    outside = 0
    checked = 0
    for k in range(n1 + n2):
        i = seeds[k] if k < n1 else seeds2[k - n1]
        if region[i] != rgen:  # listed twice
            continue
        region[i] = -rgen
        for jj in range(indptr[i], indptr[i + 1]):
            j = indices[jj]
            if not ealive[jj] or region[j] == -rgen:  # dead, or counted from j already
                continue
            checked += 1
            mid = 0.5 * (eamin[jj * ms] + eamax[jj * ms])
            half = 0.5 * (eamax[jj * ms] - eamin[jj * ms])
            b = ebeta[jj * ms]
            if dim == 3:  # unrolled, as in _walk
                d0 = np.float64(rest[j, 0]) - np.float64(rest[i, 0])
                d1 = np.float64(rest[j, 1]) - np.float64(rest[i, 1])
                d2 = np.float64(rest[j, 2]) - np.float64(rest[i, 2])
                a0 = abs(d0)
                a1 = abs(d1)
                a2 = abs(d2)
                l1 = a0 + a1 + a2
                l2 = d0 * d0 + d1 * d1 + d2 * d2
                e0 = abs(np.float64(pos[j, 0]) - np.float64(pos[i, 0]) - mid * d0) - (half * a0 + b * (l1 - a0))
                e1 = abs(np.float64(pos[j, 1]) - np.float64(pos[i, 1]) - mid * d1) - (half * a1 + b * (l1 - a1))
                e2 = abs(np.float64(pos[j, 2]) - np.float64(pos[i, 2]) - mid * d2) - (half * a2 + b * (l1 - a2))
                if e0 <= 0.0 and e1 <= 0.0 and e2 <= 0.0:
                    continue
                ex = 0.0
                if e0 > 0.0:
                    ex += e0 * e0
                if e1 > 0.0:
                    ex += e1 * e1
                if e2 > 0.0:
                    ex += e2 * e2
            else:
                l1 = 0.0
                l2 = 0.0
                for a in range(dim):
                    d = np.float64(rest[j, a]) - np.float64(rest[i, a])
                    l1 += abs(d)
                    l2 += d * d
                ex = 0.0
                for a in range(dim):
                    d = np.float64(rest[j, a]) - np.float64(rest[i, a])
                    ad = abs(d)
                    e = abs(np.float64(pos[j, a]) - np.float64(pos[i, a]) - mid * d) - (half * ad + b * (l1 - ad))
                    if e > 0.0:
                        ex += e * e
            if ex > 0.0:
                r = np.sqrt(ex) / (np.sqrt(l2) if l2 > 0.0 else 1e-300)
                if r > worst:
                    worst = r
                if r > tol:
                    outside += 1
    return worst, outside, checked


@njit(cache=True)
def _field_valid(pos, fixed, has_fixed, field_ok, field_fixed, field_ids, field_pos):
    """Whether the pin field (built for this graph and material when field_ok) was built from this fixed
    mask and these positions of the fixed elements."""
    n = pos.shape[0]
    if not (field_ok and has_fixed and field_fixed.shape[0] == n):
        return False
    for i in range(n):
        if fixed[i] != field_fixed[i]:
            return False
    for k in range(field_ids.shape[0]):
        for a in range(pos.shape[1]):
            if pos[field_ids[k], a] != field_pos[k, a]:
                return False
    return True


@njit(cache=True)
def _exact(
    rest,
    pos,
    indptr,
    indices,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    fixed,
    has_fixed,
    moved,
    grabbed,
    targets,
    eps_round,
    tol,
    max_visits,
    gen,
    pin,
    region,
    log_stamp,
    log_ids,
    x0,
    flag,
    flag_ids,
    queue,
    inq,
    dist,
    dstamp,
    dgen,
    field,
    field_ok,
    field_fixed,
    field_ids,
    field_pos,
    result,
):
    """The whole pass (see the module docstring). Writes result = [residual, outside, checked,
    shortfall, visits, complete, n changed, dgen, searched]; returns 0, or a negative code before
    anything moves. field_ok: the pin field was built for this graph and material; it is used when the
    fixed mask and the fixed elements' positions are still the ones it was built from."""
    n = pos.shape[0]
    dim = pos.shape[1]
    result[8] = 0.0
    use_field = _field_valid(pos, fixed, has_fixed, field_ok, field_fixed, field_ids, field_pos)
    for k in range(grabbed.shape[0]):
        if grabbed[k] < 0 or grabbed[k] >= n:
            return -1
        for a in range(dim):
            if not np.isfinite(targets[k, a]):
                return -3
    for k in range(moved.shape[0]):
        if moved[k] < 0 or moved[k] >= n:
            return -2
    # the direction of the pull on each axis (walk 1 goes with it) and the coordinates' magnitude
    pull = np.zeros(dim)
    scale = 0.0
    for k in range(grabbed.shape[0]):
        g = grabbed[k]
        pin[g] = gen
        if not (has_fixed and fixed[g]):
            for a in range(dim):
                pull[a] += np.float64(targets[k, a]) - np.float64(rest[g, a])
                scale = _greater(scale, abs(targets[k, a]))
    for k in range(moved.shape[0]):
        for a in range(dim):
            scale = _greater(scale, abs(np.float64(pos[moved[k], a])))
    eps_abs = eps_round * 2.0 * scale
    first = np.empty(dim, dtype=np.bool_)
    second = np.empty(dim, dtype=np.bool_)
    for a in range(dim):
        first[a] = pull[a] < 0.0
        second[a] = not first[a]
    free = False  # a grabbed element that is not fixed (only those can be settled short of a target)
    for k in range(grabbed.shape[0]):
        if not (has_fixed and fixed[grabbed[k]]):
            free = True
    visits = 0
    complete = True
    settled = False
    clamped = False
    lgen = gen
    # counts that start at zero are typed int64, not as the literal 0: numba compiles a callee once per
    # argument type, and a literal is a type of its own (one more copy of _walk per precision)
    zero = np.int64(0)
    nlog = zero
    nflag = zero
    if free and has_fixed:
        # the cascade reached a fixed element: a target may be out of reach, so settle the grabbed
        # elements before the walks rather than after a wasted walk (this reads only the pins)
        touching = False
        for k in range(moved.shape[0]):
            i = moved[k]
            for jj in range(indptr[i], indptr[i + 1]):
                if fixed[indices[jj]] and ealive[jj]:
                    touching = True
                    break
            if touching:
                break
        if touching:
            for k in range(grabbed.shape[0]):
                pin[grabbed[k]] = gen - 1  # pinned again one by one as they are settled
            v, dgen, clamped = _settle_targets(
                rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, fixed, has_fixed, pin, gen, grabbed,
                targets, dist, dstamp, dgen, queue, inq, field, use_field, result,
            )  # fmt: skip
            visits += v
            settled = True
    for attempt in range(2):
        lgen = gen + attempt
        v, _, at_fixed, nlog, nflag, ok = _walk(
            rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, fixed, has_fixed, pin, gen, first,
            moved, moved.shape[0], moved, zero, log_ids, zero, log_stamp, lgen, x0, flag_ids, zero, flag, queue, inq,
            EPS_REL, eps_abs, max_visits - visits,
        )  # fmt: skip
        visits += v
        complete = complete and ok
        if at_fixed and free and not settled:
            # the corrections reached fixed elements, so a target may be out of reach: settle the
            # grabbed elements at their nearest reachable positions now (this reads only the pins)
            for k in range(grabbed.shape[0]):
                pin[grabbed[k]] = gen - 1  # pinned again one by one as they are settled
            v, dgen, clamped = _settle_targets(
                rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, fixed, has_fixed, pin, gen, grabbed,
                targets, dist, dstamp, dgen, queue, inq, field, use_field, result,
            )  # fmt: skip
            visits += v
            settled = True
            if clamped:  # start again from the cascade's result with the grabbed elements where they stop
                _restore(pos, log_ids, x0, nlog)
                continue
        # walk 1 ended with every link it can fix inside: what is left are the links it needed a pin to
        # move for, so walk 2 starts from their ends
        v, blocked, _, nlog, nflag, ok = _walk(
            rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, fixed, has_fixed, pin, gen, second,
            flag_ids, nflag, flag_ids, zero, log_ids, nlog, log_stamp, lgen, x0, flag_ids, nflag, flag, queue,
            inq, EPS_REL, eps_abs, _greater(max_visits - visits, zero),
        )  # fmt: skip
        visits += v
        complete = complete and ok
        if blocked == 0 or settled or not free:
            break
        # walk 2 needed a pin to move: the pins are inconsistent, a target is out of reach
        _restore(pos, log_ids, x0, nlog)
        for k in range(grabbed.shape[0]):
            pin[grabbed[k]] = gen - 1
        v, dgen, clamped = _settle_targets(
            rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, fixed, has_fixed, pin, gen, grabbed,
            targets, dist, dstamp, dgen, queue, inq, field, use_field, result,
        )  # fmt: skip
        visits += v
        settled = True
    if clamped:  # the settled grabbed elements count as changed, and their links are checked
        for k in range(grabbed.shape[0]):
            if not (has_fixed and fixed[grabbed[k]]):
                nlog = _log(grabbed[k], pos, log_stamp, lgen, log_ids, x0, nlog)
    worst, outside, checked = _residual(
        rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, log_ids, nlog, flag_ids, nflag, region, gen, tol
    )
    shortfall = 0.0
    for k in range(grabbed.shape[0]):
        g = grabbed[k]
        if has_fixed and fixed[g]:
            continue
        s = 0.0
        for a in range(dim):
            s += (np.float64(targets[k, a]) - np.float64(pos[g, a])) ** 2
        shortfall = _greater(shortfall, np.sqrt(s))
    result[0] = worst
    result[1] = outside
    result[2] = checked
    result[3] = shortfall
    result[4] = visits
    result[5] = 1.0 if complete else 0.0
    result[6] = nlog
    result[7] = dgen
    return 0


@njit(cache=True, fastmath={"contract"})
def _closure_walk3(
    rest,
    pos,
    indptr,
    indices,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    cut,
    fixed,
    has_fixed,
    pin,
    gen,
    grabbed,
    targets,
    sign,
    log_ids,
    log_stamp,
    x0,
    queue,
    inq,
    excess,
    eps_abs,
    max_visits,
):
    """The exact step from a shape whose links all hold: the grabbed elements put at their targets and,
    on each axis a with sign[a] != 0, every other element moved only in that direction and only as far
    as a link forces it (the least closure of the difference constraints, module docstring), by one
    label-correcting walk (FIFO) from the grabbed elements over all axes at once. A walk reaches only the
    elements that move: a link both of whose ends keep their start positions already held.

    Fixed elements and other grabbed ones are not moved; excess[a] gets the most a link would have
    pushed a fixed one (how far the target is out of reach on that axis). cut: some link is dead (else
    the alive flags are not read). queue, log_ids and x0 hold n + 1 rows (the log and the queue are
    written before they are counted). Returns (visits, nlog, finished, conflict: a link would have
    pushed another grabbed element)."""
    qn = queue.shape[0]
    head = 0
    tail = 0
    size = 0
    nlog = 0
    for k in range(grabbed.shape[0]):
        g = grabbed[k]
        if has_fixed and fixed[g]:
            continue
        nlog = _log(g, pos, log_stamp, gen, log_ids, x0, nlog)
        for a in range(3):
            pos[g, a] = targets[k, a]
        if not inq[g]:
            inq[g] = True
            queue[tail] = g
            tail += 1
            size += 1
    visits = 0
    conflict = False
    s0 = np.float64(sign[0])
    s1 = np.float64(sign[1])
    s2 = np.float64(sign[2])
    mid = 0.5 * (eamin[0] + eamax[0])
    half = 0.5 * (eamax[0] - eamin[0])
    bt = ebeta[0]
    ex0 = 0.0
    ex1 = 0.0
    ex2 = 0.0
    while size > 0 and visits < max_visits:
        if size > _AHEAD:
            # the rows of the element served _AHEAD visits from now, asked for ahead (kernels.prefetch):
            # on a mesh larger than the caches the walk otherwise waits for them
            w = queue[head + _AHEAD - qn if head + _AHEAD >= qn else head + _AHEAD]
            prefetch(indptr, w)
            prefetch(pos, w)
            prefetch(rest, w)
            prefetch(indices, indptr[w])
        v = queue[head]
        head += 1
        if head == qn:
            head = 0
        size -= 1
        inq[v] = False
        visits += 1
        # v's rows loaded once per visit (a uniform material once per walk)
        rv0 = np.float64(rest[v, 0])
        rv1 = np.float64(rest[v, 1])
        rv2 = np.float64(rest[v, 2])
        pv0 = np.float64(pos[v, 0])
        pv1 = np.float64(pos[v, 1])
        pv2 = np.float64(pos[v, 2])
        for jj in range(indptr[v], indptr[v + 1]):
            if cut and not ealive[jj]:
                continue
            u = indices[jj]
            if ms != 0:
                mid = 0.5 * (eamin[jj] + eamax[jj])
                half = 0.5 * (eamax[jj] - eamin[jj])
                bt = ebeta[jj]
            # The bound v puts on u along axis a (5.2.2 about its centre): x_u >= x_v + mid d - w when the
            # axis moves up (s = +1), x_u <= x_v + mid d + w when down, w = half |d| + beta (l1 - |d|). u lies
            # e = s (x_v - x_u + mid d) - w behind it; the part beta l1 that every axis shares goes to the
            # threshold, so the common case (nothing to push) costs a few multiply-adds per axis. s = 0
            # gives e <= 0: no push on an axis that does not move.
            d0 = np.float64(rest[u, 0]) - rv0
            d1 = np.float64(rest[u, 1]) - rv1
            d2 = np.float64(rest[u, 2]) - rv2
            a0 = abs(d0)
            a1 = abs(d1)
            a2 = abs(d2)
            l1 = a0 + a1 + a2
            hbt = half - bt
            eps = (bt + EPS_REL) * l1 + eps_abs
            pu0 = np.float64(pos[u, 0])
            pu1 = np.float64(pos[u, 1])
            pu2 = np.float64(pos[u, 2])
            e0 = s0 * (pv0 - pu0 + mid * d0) - hbt * a0
            e1 = s1 * (pv1 - pu1 + mid * d1) - hbt * a1
            e2 = s2 * (pv2 - pu2 + mid * d2) - hbt * a2
            h0 = e0 > eps
            h1 = e1 > eps
            h2 = e2 > eps
            if not (h0 | h1 | h2):
                continue
            btl = bt * l1
            e0 -= btl
            e1 -= btl
            e2 -= btl
            if has_fixed and fixed[u]:
                ex0 = e0 if h0 and e0 > ex0 else ex0
                ex1 = e1 if h1 and e1 > ex1 else ex1
                ex2 = e2 if h2 and e2 > ex2 else ex2
                continue
            if pin[u] == gen:
                conflict = True
                continue
            # u's start position logged the first time it moves: written every time and counted once,
            # selects where branches on whether u moved before would be mispredicted
            log_ids[nlog] = u
            x0[nlog, 0] = pu0
            x0[nlog, 1] = pu1
            x0[nlog, 2] = pu2
            nlog += log_stamp[u] != gen
            log_stamp[u] = gen
            pos[u, 0] = pu0 + s0 * e0 if h0 else pu0
            pos[u, 1] = pu1 + s1 * e1 if h1 else pu1
            pos[u, 2] = pu2 + s2 * e2 if h2 else pu2
            queue[tail] = u
            q = not inq[u]
            inq[u] = True
            tail += q
            size += q
            if tail == qn:
                tail = 0
    excess[0] = ex0
    excess[1] = ex1
    excess[2] = ex2
    finished = size == 0
    while size > 0:  # leave the queue flags clean
        inq[queue[head]] = False
        head += 1
        if head == qn:
            head = 0
        size -= 1
    return visits, nlog, finished, conflict


@njit(cache=True)
def _closure_walk_nd(
    rest,
    pos,
    indptr,
    indices,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    fixed,
    has_fixed,
    pin,
    gen,
    grabbed,
    targets,
    sign,
    log_ids,
    log_stamp,
    x0,
    queue,
    inq,
    excess,
    eps_abs,
    max_visits,
):
    """_closure_walk3 for one or two axes (the same walk, a loop over the axes; read that one first).

    The exact step from a shape whose links all hold: the grabbed elements put at their targets and,
    on each axis a with sign[a] != 0, every other element moved only in that direction and only as far
    as a link forces it (the least closure of the difference constraints, module docstring), by one
    label-correcting walk from the grabbed elements over all axes at once. A walk reaches only the
    elements that move: a link both of whose ends keep their start positions already held.

    Fixed elements and other grabbed ones are not moved; excess[a] gets the most a link would have
    pushed a fixed one (how far the target is out of reach on that axis). Returns (visits, nlog,
    finished, conflict: a link would have pushed another grabbed element)."""
    n = pos.shape[0]
    dim = pos.shape[1]
    head = 0
    tail = 0
    size = 0
    nlog = 0
    for k in range(grabbed.shape[0]):
        g = grabbed[k]
        if has_fixed and fixed[g]:
            continue
        nlog = _log(g, pos, log_stamp, gen, log_ids, x0, nlog)
        for a in range(dim):
            pos[g, a] = targets[k, a]
        if not inq[g]:
            inq[g] = True
            queue[tail] = g
            tail += 1
            size += 1
    if tail == n:
        tail = 0
    for a in range(dim):
        excess[a] = 0.0
    visits = 0
    conflict = False
    s0 = np.float64(sign[0])
    s1 = np.float64(sign[1]) if dim > 1 else 0.0
    while size > 0 and visits < max_visits:
        v = queue[head]
        head += 1
        if head == n:
            head = 0
        size -= 1
        inq[v] = False
        visits += 1
        mid = 0.5 * (eamin[0] + eamax[0])
        half = 0.5 * (eamax[0] - eamin[0])
        bt = ebeta[0]
        for jj in range(indptr[v], indptr[v + 1]):
            if not ealive[jj]:
                continue
            u = indices[jj]
            if ms != 0:
                mid = 0.5 * (eamin[jj] + eamax[jj])
                half = 0.5 * (eamax[jj] - eamin[jj])
                bt = ebeta[jj]
            moved = False
            l1 = 0.0
            for a in range(dim):
                l1 += abs(np.float64(rest[u, a]) - np.float64(rest[v, a]))
            eps = EPS_REL * l1 + eps_abs
            for a in range(dim):
                s = s0 if a == 0 else s1
                if s == 0.0:
                    continue
                d = np.float64(rest[u, a]) - np.float64(rest[v, a])
                ad = abs(d)
                cand = np.float64(pos[v, a]) + mid * d - s * (half * ad + bt * (l1 - ad))
                ex = s * (cand - np.float64(pos[u, a]))
                if ex <= eps:
                    continue
                if has_fixed and fixed[u]:
                    excess[a] = _greater(excess[a], ex)
                    continue
                if pin[u] == gen:
                    conflict = True
                    continue
                if log_stamp[u] != gen:
                    nlog = _log(u, pos, log_stamp, gen, log_ids, x0, nlog)
                pos[u, a] = cand
                moved = True
            if moved and not inq[u]:
                inq[u] = True
                queue[tail] = u
                tail += 1
                if tail == n:
                    tail = 0
                size += 1
    finished = size == 0
    while size > 0:  # leave the queue flags clean
        inq[queue[head]] = False
        head += 1
        if head == n:
            head = 0
        size -= 1
    return visits, nlog, finished, conflict


@njit(cache=True)
def _exact_move(
    rest,
    pos,
    indptr,
    indices,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    cut,
    fixed,
    has_fixed,
    grabbed,
    targets,
    eps_round,
    tol,
    max_visits,
    gen,
    stamps,
    log_ids,
    x0,
    queue,
    inq,
    check,
    field,
    field_ok,
    field_fixed,
    field_ids,
    field_pos,
):
    """exact_move's kernel (see the module docstring, "The exact step"). stamps: the workspace's pin,
    region and log stamps as rows; field...: the pin field, as for _exact. Returns (code, n changed,
    visits, complete, fallback, residual, outside, checked, shortfall, searched): code 0, or a negative
    code before anything moves; fallback: the grabbed elements pull one axis both ways or one stops
    another, so the caller settles them with the cascade and the walks (pos is then as on entry);
    searched: a target out of reach was found by the walk, not read from the field."""
    n = pos.shape[0]
    dim = pos.shape[1]
    pin = stamps[0]
    region = stamps[1]
    log_stamp = stamps[2]
    for k in range(grabbed.shape[0]):
        if grabbed[k] < 0 or grabbed[k] >= n:
            return -1, 0, 0, True, False, 0.0, 0, 0, 0.0, False
        for a in range(dim):
            if not np.isfinite(targets[k, a]):
                return -3, 0, 0, True, False, 0.0, 0, 0, 0.0, False
    nfree = 0
    for k in range(grabbed.shape[0]):
        nfree += not (has_fixed and fixed[grabbed[k]])
    # One grabbed element against the fixed ones, whose reachable boxes a drag has already computed (the
    # pin field, as exact_limits reads it): its target clamped into its box first, so the walk reaches
    # only the elements that end somewhere else instead of spreading from the target out of reach.
    tg = targets
    clamped = False
    if nfree == 1 and _field_valid(pos, fixed, has_fixed, field_ok, field_fixed, field_ids, field_pos):
        tg = targets.copy()
        clamped = True
        for k in range(grabbed.shape[0]):
            g = grabbed[k]
            if fixed[g]:
                continue
            for a in range(dim):
                r = np.float64(rest[g, a])
                x = tg[k, a]
                if field[g, 2 * a] < x - r:
                    x = r + field[g, 2 * a]
                if field[g, 2 * a + 1] < r - x:
                    x = r - field[g, 2 * a + 1]
                tg[k, a] = x
    sign = np.zeros(3, dtype=np.int64)
    scale = 0.0
    mixed = False
    for k in range(grabbed.shape[0]):
        g = grabbed[k]
        pin[g] = gen
        if has_fixed and fixed[g]:
            continue
        for a in range(dim):
            step = np.float64(tg[k, a]) - np.float64(pos[g, a])
            s = 1 if step > 0.0 else (-1 if step < 0.0 else 0)
            if s != 0:
                if sign[a] == -s:
                    mixed = True
                sign[a] = s
            scale = _greater(scale, _greater(abs(targets[k, a]), abs(np.float64(pos[g, a]))))
    if mixed:
        return 0, 0, 0, True, True, 0.0, 0, 0, 0.0, False
    eps_abs = eps_round * 2.0 * scale
    excess = np.zeros(3)
    if dim == 3:
        visits, nlog, finished, conflict = _closure_walk3(
            rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, cut, fixed, has_fixed, pin, gen, grabbed,
            tg, sign, log_ids, log_stamp, x0, queue, inq, excess, eps_abs, max_visits,
        )  # fmt: skip
    else:
        visits, nlog, finished, conflict = _closure_walk_nd(
            rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, fixed, has_fixed, pin, gen, grabbed, tg,
            sign, log_ids, log_stamp, x0, queue, inq, excess, eps_abs, max_visits,
        )  # fmt: skip
    out_of_reach = excess[0] > 0.0 or excess[1] > 0.0 or excess[2] > 0.0
    if conflict or (out_of_reach and nfree > 1):
        _restore(pos, log_ids, x0, nlog)
        return 0, 0, 0, True, True, 0.0, 0, 0, 0.0, False
    # One grabbed element out of reach on some axes by excess[a]: its nearest reachable position is the
    # target moved back by that much (the per-axis clamp into its reachable box: the fixed element that
    # bound hardest lies at dist from it), and every label the walk set moves back with it, to no less
    # than where the element started (5.2.2 closures of the clamped target; see the docstring). In the
    # same pass only the elements that end somewhere else are kept.
    back = np.zeros(3)
    for a in range(dim):
        back[a] = np.float64(sign[a]) * excess[a]
    m = 0
    for k in range(nlog):
        i = log_ids[k]
        same = True
        for a in range(dim):
            x = np.float64(pos[i, a])
            if out_of_reach and back[a] != 0.0:
                x -= back[a]
                if (x - x0[k, a]) * sign[a] < 0.0:
                    x = x0[k, a]
                pos[i, a] = x
            if pos[i, a] != x0[k, a]:
                same = False
        if same:
            log_stamp[i] = gen - 1
        else:
            log_ids[m] = i
            for a in range(dim):
                x0[m, a] = x0[k, a]
            m += 1
    worst = 0.0
    outside = 0
    checked = 0
    if check:
        worst, outside, checked = _residual(
            rest, pos, indptr, indices, ealive, eamin, eamax, ebeta, ms, log_ids, m, log_ids, 0, region, gen, tol
        )
    shortfall = 0.0
    for k in range(grabbed.shape[0]):
        g = grabbed[k]
        if has_fixed and fixed[g]:
            continue
        s2 = 0.0
        for a in range(dim):
            s2 += (np.float64(targets[k, a]) - np.float64(pos[g, a])) ** 2
        shortfall = _greater(shortfall, np.sqrt(s2))
    return 0, m, visits, finished, False, worst, outside, checked, shortfall, out_of_reach and not clamped


# ----------------------------------------------------------------------------------------------------
# Python entry point

_INT64 = np.dtype(np.int64)
_BOOL = np.dtype(np.bool_)
_NO_FIXED = np.zeros(1, dtype=np.bool_)


def exact_limits(
    rest,
    pos,
    graph: Graph,
    amin,
    amax,
    beta,
    moved,
    grabbed,
    targets=None,
    fixed=None,
    workspace=None,
    max_visits: int | None = None,
) -> ExactResult:
    """After a cascade (and relaxation): put every link touching the moved region back inside its box,
    in place. Grabbed and fixed elements stay put, unless a grabbed element's target cannot be reached
    within the limits from the fixed ones: it then goes to the reachable position nearest its target.

    rest, pos, graph, amin, amax, beta: as for cascade (pos holds the cascade's result). moved: the ids
    the cascade moved (its first return value). grabbed: the grabbed ids; targets: where they were asked
    to go ((K, D); default: where they are). fixed: bool (N,) or None, as for the cascade (held elements
    included). workspace: the body's cascade Workspace (the pass keeps its scratch on it).
    max_visits: cap on element visits (default 64 N + 10^4). Raises ValueError on bad ids or targets
    (pos is then untouched).

    Assumes the links outside the moved region are inside their boxes (what an exact step leaves); it
    looks no further than the corrections spread.
    """
    n, dim = pos.shape
    if type(rest) is not np.ndarray or rest.shape != pos.shape or rest.dtype != pos.dtype:
        raise ValueError(f"rest must match pos in shape {pos.shape} and dtype {pos.dtype}")
    if type(moved) is not np.ndarray or moved.dtype != _INT64 or moved.ndim != 1:
        moved = np.ascontiguousarray(np.atleast_1d(moved), dtype=np.int64)
    if type(grabbed) is not np.ndarray or grabbed.dtype != _INT64 or grabbed.ndim != 1:
        grabbed = np.ascontiguousarray(np.atleast_1d(grabbed), dtype=np.int64)
    if targets is None:
        targets = pos[np.clip(grabbed, 0, max(n - 1, 0))].astype(np.float64)
    elif type(targets) is not np.ndarray or targets.shape != (len(grabbed), dim) or targets.dtype != np.float64:
        targets = np.ascontiguousarray(targets, dtype=np.float64).reshape(len(grabbed), dim)
    fixed_arr, has_fixed = fixed_mask(fixed, n)
    if n == 0:
        return ExactResult(np.zeros(0, np.int64), 0.0, 0, 0, 0.0, 0, True)
    ex = exact_workspace(workspace, n, dim)
    cap = int(max_visits) if max_visits is not None else 64 * n + 10_000
    gen = ex.next_generation()
    if amin is not None or amax is not None or beta is not None:
        graph.bind_materials(amin, amax, beta)
    code = _exact(
        rest, pos, *graph.kernel_args, fixed_arr, has_fixed,
        moved, grabbed, targets, _ROUND[pos.dtype], TOL[pos.dtype], cap, gen, ex.pin, ex.region, ex.log_stamp,
        ex.log_ids, ex.x0, ex.flag, ex.flag_ids, ex.queue, ex.inq, ex.dist, ex.dstamp, ex.dgen,
        *ex.field_args(graph), ex.result,
    )  # fmt: skip
    if code < 0:
        raise ValueError(_ERRORS[code].replace("N)", f"{n})"))
    r = ex.result
    if r[8]:
        ex.searched(rest, pos, graph, fixed_arr)
    ex.dgen = int(r[7])
    nchanged = int(r[6])
    return ExactResult(
        ex.log_ids[:nchanged].copy(), float(r[0]), int(r[1]), int(r[2]), float(r[3]), int(r[4]), bool(r[5])
    )


def exact_move(
    rest,
    pos,
    graph: Graph,
    amin,
    amax,
    beta,
    grabbed,
    targets,
    fixed=None,
    workspace=None,
    order: int = 0,
    max_visits: int | None = None,
    check: bool = False,
) -> tuple[np.ndarray, ExactResult]:
    """One exact step instead of a cascade followed by exact_limits: move `grabbed` to `targets` and every
    other element to the nearest position that keeps every link inside its box, in place (module
    docstring, "The exact step"). Fixed (and held) elements stay put; a grabbed element whose target
    the fixed ones put out of reach stops at the nearest reachable position (`shortfall` says how far).

    Arguments as for cascade and exact_limits. `pos` must have every link inside its box (the rest shape,
    or what an exact step left); where it does not, the links the step checks that are still outside
    are put back by exact_limits' walks. Several grabbed elements that pull one axis both ways, or that
    stop one another, are settled as before: the cascade (in `order`) and then exact_limits.

    check: also measure every link of the changed elements (residual, outside, checked) and put back with
    the walks any still outside (a start shape with links outside); without it the step relies on its
    proof and reports checked = 0 (a whole-mesh check costs about a walk more).

    Returns (changed ids, each once, int64; ExactResult); `changed` is a view into the workspace, valid
    until its next step. Raises ValueError on bad ids or targets (pos is then untouched).
    """
    ex = getattr(workspace, "exact", None) if workspace is not None else None
    n, dim = pos.shape
    if ex is None or ex.n != n or ex.dim != dim:
        ex = exact_workspace(workspace, n, dim)
    if amin is not None and not (amin is graph.amin and amax is graph.amax and beta is graph.beta):
        graph.bind_materials(amin, amax, beta)
    if type(grabbed) is not np.ndarray or grabbed.dtype != _INT64 or grabbed.ndim != 1:
        grabbed = np.ascontiguousarray(np.atleast_1d(grabbed), dtype=np.int64)
    if type(targets) is not np.ndarray or targets.shape != (len(grabbed), dim) or targets.dtype != np.float64:
        targets = np.ascontiguousarray(targets, dtype=np.float64).reshape(len(grabbed), dim)
    if fixed is None:
        fixed_arr, has_fixed = _NO_FIXED, False
    elif type(fixed) is np.ndarray and fixed.dtype == _BOOL and fixed.shape == (n,) and fixed.flags.c_contiguous:
        fixed_arr, has_fixed = fixed, True
    else:
        fixed_arr, has_fixed = fixed_mask(fixed, n)
    kargs, cut = ex.step_args(graph, workspace)
    cap = int(max_visits) if max_visits is not None else 64 * n + 10_000
    code, m, visits, complete, fallback, worst, outside, checked, shortfall, searched = _exact_move(
        rest, pos, *kargs, cut, fixed_arr, has_fixed, grabbed, targets, _ROUND[pos.dtype],
        TOL[pos.dtype], cap, ex.next_generation(), ex.stamps, ex.log_ids, ex.x0, ex.queue, ex.inq, bool(check),
        *ex.field_args(graph),
    )  # fmt: skip
    if code < 0:
        raise ValueError(_ERRORS[code].replace("N)", f"{n})"))
    if searched:  # out of reach again with the same fixed elements: a drag; their field is built once
        ex.searched(rest, pos, graph, fixed_arr)
    if fallback:  # both ways on an axis, or grabbed elements in one another's way: the cascade and the walks
        moved, _ = cascade(
            rest, pos, graph, None, None, None, grabbed, targets.astype(pos.dtype), fixed=fixed, order=order,
            workspace=workspace,
        )  # fmt: skip
        res = exact_limits(rest, pos, graph, None, None, None, moved, grabbed, targets, fixed, workspace, max_visits)
        return np.union1d(moved, res.changed), res
    changed = ex.log_ids[:m]
    if outside:  # the start shape had links outside: the walks put back those the step checked
        res = exact_limits(rest, pos, graph, None, None, None, changed.copy(), grabbed, targets, fixed, workspace)
        return np.union1d(changed, res.changed), res._replace(visits=res.visits + visits)
    return changed, ExactResult(changed, worst, 0, checked, shortfall, visits, complete)


class Violations(NamedTuple):
    """How far a configuration breaks the limits, over every live link.

    share:   fraction of live links outside their box by more than TOL of their rest length
    worst:   largest distance of a link from its box, as a multiple of its rest length
    outside: number of links outside (as for share)
    links:   number of live links
    """

    share: float
    worst: float
    outside: int
    links: int


def violations(rest, pos, graph: Graph, amin, amax, beta) -> Violations:
    """Off-chain violation figures of `pos` (numpy, over the whole mesh: for reports, not per frame).

    A link's box is the valid region of 5.2.2 for one end with respect to the other (the same whichever
    end is taken as sponsor); its distance from the box is the Euclidean norm of the per-axis excesses.
    """
    if amin is None:
        amin, amax, beta = graph.amin, graph.amax, graph.beta
    live = np.flatnonzero(graph.alive)
    if live.size == 0:
        return Violations(0.0, 0.0, 0, 0)
    a, b = graph.links[live, 0], graph.links[live, 1]
    d = rest[b].astype(np.float64) - rest[a].astype(np.float64)
    u = pos[b].astype(np.float64) - pos[a].astype(np.float64)
    ad = np.abs(d)
    other = ad.sum(axis=1, keepdims=True) - ad
    lo_, hi_ = amin[live, None], amax[live, None]
    e = np.abs(u - 0.5 * (lo_ + hi_) * d) - (0.5 * (hi_ - lo_) * ad + beta[live, None] * other)
    dist = np.sqrt((np.maximum(e, 0.0) ** 2).sum(axis=1))
    ratio = dist / np.maximum(np.sqrt((d * d).sum(axis=1)), 1e-300)
    out = int(np.count_nonzero(ratio > TOL[np.dtype(pos.dtype)]))
    return Violations(out / live.size, float(ratio.max()), out, int(live.size))

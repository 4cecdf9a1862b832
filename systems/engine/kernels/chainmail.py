"""Generalised ChainMail cascade (thesis 5.2): one kernel for curves, sheets and volumes in 1-, 2- or 3-D.

A cascade starts from a set of grabbed elements moved explicitly to targets (a tool's contact patch) and
spreads over the link graph: each candidate is checked against the valid box spanned by its sponsor's
new position and the REST link vector (5.2.2, 5.2.6). A candidate inside its box stays put and does not
propagate; one outside is clamped to the nearest point of the box, and its neighbours become candidates
with it as sponsor (5.2.3). Every element moves at most once per cascade (termination, 5.2.4), and an
element that has not moved may be checked again by a later sponsor.

Four orders for the waiting list:
  ORDER_BREADTH_FIRST  a plain queue;
  ORDER_DEPTH_FIRST    the list exactly as 5.2.3 words it: a moved element's neighbours go to the FRONT of
                       the waiting list, in their listed order, so one branch runs to its leaves first;
  ORDER_BALANCED       the round robin of 5.2.3 (Fig. 5.3): one branch per candidate enqueued by the grabbed
                       elements, each branch advanced `depth` levels per turn, then paused while the others go;
  ORDER_SCHILL         largest constraint violation first (binary heap), the inhomogeneous-material ordering
                       that 4.2.2 attributes to Schill et al.; pairs with per-link materials.

Whatever the order, a link is only guaranteed inside its box against the sponsor that moved its element:
5.2.4 bounds the link between two elements moved by one sponsor by a WIDENED box, not by the link's own
box, and says nothing of elements moved by different sponsors. kernels.exact puts every link back inside.

Cost follows what moves: the "already moved" flag is a generation stamp in a reusable Workspace, so
nothing of size N is cleared or allocated per cascade. The breadth-first loop asks which of a sponsor's
neighbours have not moved sixteen entries at a time (kernels.gather) and visits only those; it asks a few
sponsors ahead of their turn, so the rows of the first such neighbour are on their way from memory by
then, and keeps the answer for the turn itself. On 3-D meshes it walks the neighbour lists as rows of
sixteen ids, one cache line each (Workspace.rows16): a sponsor's list is then one line fetched and one
vector load, with no row start to look up first.

Material limits are per link (arrays of length M), so inhomogeneous tissue is just different numbers on
different links. With d = rest[B] - rest[A] and o_a the sum of |d_b| over the other axes, the box on axis
a is [A*_a + amin|d_a| - beta o_a, A*_a + amax|d_a| + beta o_a] when d_a >= 0, mirrored when d_a < 0
(kernels.boxes). The kernels read the alive flags and materials in CSR entry order from the Graph, which
owns them (one value per material when every link shares it), so they stream with the neighbour ids.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit

from . import waves
from .boxes import start_cascade, try_move, violation
from .gather import LANES, lowest_bit, unmoved_mask
from .graph import Graph
from .prefetch import prefetch

ORDER_BREADTH_FIRST = 0
ORDER_BALANCED = 1
ORDER_SCHILL = 2
ORDER_DEPTH_FIRST = 3
_ORDERS = (ORDER_BREADTH_FIRST, ORDER_BALANCED, ORDER_SCHILL, ORDER_DEPTH_FIRST)

_NO_FIXED = np.zeros(1, dtype=np.bool_)
_GEN_LIMIT = 254  # byte stamps (255 marks the overflow lane): generations 1 to 253, then cleared


# ----------------------------------------------------------------------------------------------------
# materials


def material_arrays(n_links, alpha_min, alpha_max, beta, dtype=np.float64) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-link (amin, amax, beta) arrays of length `n_links` from scalars or per-link arrays.

    alpha_min in [0, 1] limits compression, alpha_max >= 1 stretching, beta >= 0 shear (5.2.2); all
    finite. Raises ValueError naming the offending parameter and link.
    """
    n_links = int(n_links)
    if n_links < 0:
        raise ValueError(f"n_links must be >= 0, got {n_links}")
    out = []
    for name, value in (("alpha_min", alpha_min), ("alpha_max", alpha_max), ("beta", beta)):
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a number or an array of numbers, got {value!r}") from None
        if arr.ndim == 0:
            arr = np.full(n_links, float(arr))
        elif arr.shape != (n_links,):
            raise ValueError(f"{name} must be a scalar or have one value per link ({n_links},), got shape {arr.shape}")
        else:
            arr = arr.copy()
        if not np.all(np.isfinite(arr)):
            bad = int(np.flatnonzero(~np.isfinite(arr))[0])
            raise ValueError(f"{name} must be finite, got {arr[bad]} (link {bad})")
        out.append(arr)
    amin, amax, bet = out
    checks = (
        (amin < 0.0, "alpha_min", amin, "must be >= 0 (0 = may collapse completely)"),
        (amin > 1.0, "alpha_min", amin, "must be <= 1 (rest length must stay allowed)"),
        (amax < 1.0, "alpha_max", amax, "must be >= 1 (rest length must stay allowed)"),
        (bet < 0.0, "beta", bet, "must be >= 0"),
    )
    for mask, name, arr, why in checks:
        if np.any(mask):
            bad = int(np.flatnonzero(mask)[0])
            raise ValueError(f"{name} {why}, got {arr[bad]} (link {bad})")
    return (
        np.ascontiguousarray(amin, dtype=dtype),
        np.ascontiguousarray(amax, dtype=dtype),
        np.ascontiguousarray(bet, dtype=dtype),
    )


# ----------------------------------------------------------------------------------------------------
# workspace


class Workspace:
    """Scratch reused across cascades on one mesh.

    stamp[i] == gen means element i has moved in the current cascade; bumping `gen` clears every flag
    at once. Stamps are bytes, so a million elements' fit in a core's own cache, and every 253rd
    generation clears them in one pass. The output buffers are N long; the waiting-list buffers of the
    balanced and Schill orders are grown on demand (to the CSR size plus K) and then kept. The
    breadth-first order needs no queue: on 3-D meshes it walks the neighbour lists as rows of sixteen
    (`rows16`), otherwise a copy of the graph's CSR arrays in int32 (`csr32`, made once per graph when the
    sizes fit), half the bytes of the neighbour lists it streams, which on large meshes is much of its
    time.
    """

    def __init__(self, n: int):
        n = int(n)
        if n < 0:
            raise ValueError(f"workspace size must be >= 0, got {n}")
        self.n = n
        # one byte a stamp (the whole array stays in a core's cache up to a few million elements), and two
        # more than elements: the padding (n) and overflow (n + 1) lanes of the 3-D loop's rows; the three
        # bytes after them are for the gather, which reads a byte stamp as the low byte of four
        self.stamp = np.zeros(n + 5, dtype=np.uint8)[: n + 2]
        self.gen = 0
        self.out_order = np.empty(n, dtype=np.int64)
        self.out_sponsor = np.empty(n, dtype=np.int64)
        self.q_entry = np.empty(0, dtype=np.int32)  # CSR entry index (gives element and link)
        self.q_sponsor = np.empty(0, dtype=np.int32)
        self.q_aux = np.empty(0, dtype=np.int32)  # depth (balanced) or sequence number (Schill)
        self.q_next = np.empty(0, dtype=np.int32)  # branch linked lists (balanced)
        self.q_key = np.empty(0, dtype=np.float64)  # violation (Schill)
        self.branch_head = np.empty(0, dtype=np.int64)
        self.branch_tail = np.empty(0, dtype=np.int64)
        self.csr32: tuple | None = None  # (graph, indptr, indices, padded indices) in int32 for the breadth-first order
        self.rows16_kept: tuple | None = None  # (graph, rows) for the 3-D breadth-first loop (rows16)
        # The mesh arrays last checked with this workspace, held (not just their ids) so an identity
        # match means the very same arrays: interactive dragging re-checks only pos, grabbed, targets.
        self.checked: tuple = ()

    def ensure(self, capacity: int, order: int = ORDER_BALANCED, branches: int | None = None) -> None:
        """Make the waiting-list buffers hold `capacity` entries for `order` (breadth-first needs none).

        `capacity` bounds the entries one cascade can queue: the CSR size plus K. Entries are int32
        while that fits, halving the memory of the queued orders on big meshes.
        `branches` (balanced order) bounds the branches, i.e. the links of the grabbed elements.
        """
        if order == ORDER_BREADTH_FIRST:
            return
        cap = max(int(capacity), 16)
        idx = np.int32 if cap < 2**31 - 1 else np.int64
        if cap > self.q_entry.shape[0] or (idx is np.int64 and self.q_entry.dtype != np.int64):
            self.q_entry = np.empty(cap, dtype=idx)
            self.q_sponsor = np.empty(cap, dtype=idx)
            self.q_aux = np.empty(cap, dtype=idx)
        if order == ORDER_BALANCED:
            if cap > self.q_next.shape[0] or self.q_next.dtype != self.q_entry.dtype:
                self.q_next = np.empty(cap, dtype=self.q_entry.dtype)
            nb = cap if branches is None else max(int(branches), 16)
            if nb > self.branch_head.shape[0]:
                self.branch_head = np.empty(nb, dtype=np.int64)
                self.branch_tail = np.empty(nb, dtype=np.int64)
        if order == ORDER_SCHILL and cap > self.q_key.shape[0]:
            self.q_key = np.empty(cap, dtype=np.float64)

    def narrow_csr(self, graph: Graph, kargs: tuple, padded: bool = False) -> tuple:
        """kargs with the CSR arrays in int32 when they fit (kept per graph: a Graph's neighbour lists
        never change, cuts only flip alive flags; added links make a new Graph). With `padded` the
        neighbour ids are followed by sixteen zeros, so that kernels.gather may read sixteen ids from
        any entry on (the breadth-first loop); otherwise they are a view of exactly 2M ids."""
        c = self.csr32
        if c is None or c[0] is not graph:
            if graph.indices.shape[0] >= 2**31 - 1:
                return kargs
            m = graph.indices.shape[0]
            ids = np.zeros(m + LANES, dtype=np.int32)
            ids[:m] = graph.indices
            c = self.csr32 = (graph, graph.indptr.astype(np.int32), ids[:m], ids)
        return (c[1], c[3] if padded else c[2], *kargs[2:])

    def rows16(self, graph: Graph) -> np.ndarray:
        """The graph's neighbour lists as rows of sixteen int32 ids, each row one 64-byte cache line (kept
        per graph, like csr32): what the 3-D breadth-first loop walks. A row holds its element's first
        fifteen neighbours in CSR order; its unused lanes hold n (an element id whose stamp always reads
        "moved") and its last lane, for an element with more than fifteen neighbours, n + 1 (whose stamp
        never does), which sends the loop to the CSR lists for the rest. Empty when ids do not fit int32."""
        c = self.rows16_kept
        if c is None or c[0] is not graph:
            n = graph.indptr.shape[0] - 1
            if n + 2 >= 2**31 - 1:  # the padding and overflow ids must fit int32 too
                return _NO_ROWS
            raw = np.empty(LANES * (n + 2), dtype=np.int32)  # a row's worth of slack for the alignment
            first = (-raw.ctypes.data % 64) // 4
            rows = raw[first : first + LANES * n]
            _fill_rows(graph.indptr, graph.indices, rows, n)
            c = self.rows16_kept = (graph, rows)
        return c[1]

    def next_generation(self) -> int:
        self.gen += 1
        if self.gen >= _GEN_LIMIT:  # every 253rd cascade: the one pass over the stamps that keeps them unambiguous
            self.stamp[:] = 0
            self.gen = 1
        return self.gen


_NO_ROWS = np.zeros(0, dtype=np.int32)


@njit(cache=True)
def _fill_rows(indptr, indices, rows, n):
    for i in range(n):
        lo = indptr[i]
        deg = indptr[i + 1] - lo
        for k in range(LANES - 1):
            rows[LANES * i + k] = indices[lo + k] if k < deg else n
        rows[LANES * i + LANES - 1] = n + 1 if deg > LANES - 1 else n


def make_workspace(n: int) -> Workspace:
    """Workspace for a mesh of `n` elements; pass it to every cascade on that mesh."""
    return Workspace(n)


# ----------------------------------------------------------------------------------------------------
# kernels (the valid region and the move into it: kernels.boxes)


#: how many queued sponsors ahead the breadth-first loop asks for rows: far enough that a load from
#: memory has landed when the sponsor is served (about a microsecond of work), near enough that the rows
#: are still cached then; the CSR row start is asked for twice as far ahead, so that the neighbour list
#: itself can be asked for at the nearer distance
_AHEAD = 12
#: how many queued sponsors ahead it finds which of a sponsor's neighbours have not moved and asks for
#: the first one's rows: once that sponsor's neighbour list has arrived (asked for _AHEAD sponsors ahead), and early
#: enough for the rows
_NEAR = 6


#: the look-ahead ring: the unmoved-neighbour masks found _NEAR sponsors ahead wait there for their
#: sponsor's turn (slot = queue index mod _RING, a power of two above _NEAR), with the sponsor's id, so that
#: the turn itself needs no second gather; the mask is a superset then (stamps only ever turn to the current
#: generation) and each entry's stamp is read again before its check
_RING = 8


@njit(cache=True, inline="always")
def _box_lo_hi(b, d, a, o, am, ax, be):
    """The interval of 5.2.2 on one axis around sponsor coordinate b (mirrored for d < 0), as selects
    rather than branches: d's sign follows no pattern a branch predictor could learn. b - x is b + (-x)
    exactly, so this is bit for bit the branching form of kernels.boxes."""
    w_lo = am * a - be * o
    w_hi = ax * a + be * o
    pos_side = d >= 0.0
    lo = b + (w_lo if pos_side else -w_hi)
    hi = b + (w_hi if pos_side else -w_lo)
    return lo, hi


@njit(cache=True)
def _cascade_fifo(
    rest,
    pos,
    indptr,
    indices,
    rows,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    grabbed,
    targets,
    fixed,
    has_fixed,
    stamp,
    gen,
    out_order,
    out_sponsor,
    has_dead=True,
):
    # With a FIFO waiting list the first queued entry for an element that violates its box is the one
    # that moves it: neither its position nor its (already moved) sponsor's changes before that entry
    # is served. So the move can be made when the entry is queued, and the output list doubles as the
    # queue: each element is queued at most once, like a breadth-first search.
    count = start_cascade(pos, grabbed, targets, fixed, has_fixed, stamp, gen, out_order, out_sponsor)
    if count < 0:
        return count
    return _fifo_loop(
        rest, pos, indptr, indices, rows, ealive, has_dead, eamin, eamax, ebeta, ms, fixed, has_fixed, stamp, gen,
        out_order, out_sponsor, count,
    )  # fmt: skip


@njit(cache=True)
def _fifo_loop(
    rest, pos, indptr, indices, rows, ealive, has_dead, eamin, eamax, ebeta, ms, fixed, has_fixed, stamp, gen,
    out_order, out_sponsor, count,
):  # fmt: skip
    """The breadth-first cascade from the grabbed elements out_order[:count] (moved and stamped).
    Returns the final count. 3-D meshes walk the rows of sixteen (Workspace.rows16) where given."""
    if pos.shape[1] == 3 and rows.shape[0] > 0:
        return _fifo_loop_3d(
            rest, pos, indptr, indices, rows, ealive, has_dead, eamin, eamax, ebeta, ms, fixed, has_fixed, stamp, gen,
            out_order, out_sponsor, count,
        )  # fmt: skip
    return _fifo_loop_nd(
        rest, pos, indptr, indices, ealive, has_dead, eamin, eamax, ebeta, ms, fixed, has_fixed, stamp, gen, out_order,
        out_sponsor, count,
    )  # fmt: skip


@njit(cache=True)
def _fifo_loop_3d(
    rest, pos, indptr, indices, rows, ealive, has_dead, eamin, eamax, ebeta, ms, fixed, has_fixed, stamp, gen,
    out_order, out_sponsor, count,
):  # fmt: skip
    n = pos.shape[0]
    stamp[n] = gen  # the rows' padding lanes: never a candidate
    stamp[n + 1] = 255  # their overflow lane: always looked at (generations are 1 to 254)
    # one material for every link (ms == 0): its limits read once, not per candidate
    am = eamin[0]
    ax = eamax[0]
    be = ebeta[0]
    owners = np.full(_RING, -1, dtype=np.int64)
    masks = np.zeros(_RING, dtype=np.int64)
    head = 0
    while head < count:
        # Once every element has moved no check can move another: the sponsors still queued (the last
        # wave, when a drag carries the whole body) have nothing left to do (never, with an anchor).
        if count == n:
            break
        # The rows of the sponsors served next, asked for ahead (kernels.prefetch): on a mesh larger than
        # the caches, waiting for them is most of a cascade's time. _NEAR ahead, which of a sponsor's
        # neighbours have not moved (kept in the ring for its turn) and the rows of the first of them: asking
        # for all of them costs more, where a cascade ends, than it saves. (A wasted prefetch, or one past
        # the end for n + 1, changes nothing.)
        if head + 2 * _AHEAD < count:
            s2 = out_order[head + 2 * _AHEAD]
            prefetch(rows, LANES * s2)
            prefetch(pos, s2)
            prefetch(rest, s2)
        if head + _NEAR < count:
            s0 = out_order[head + _NEAR]
            ahead = unmoved_mask(rows, LANES * s0, LANES, stamp, gen)
            slot = (head + _NEAR) & (_RING - 1)
            owners[slot] = s0
            masks[slot] = ahead
            e0 = rows[LANES * s0 + lowest_bit(ahead)] if ahead != 0 else s0
            prefetch(pos, e0)
            prefetch(rest, e0)
        s = out_order[head]
        slot = head & (_RING - 1)
        head += 1
        mask = masks[slot] if owners[slot] == s else unmoved_mask(rows, LANES * s, LANES, stamp, gen)
        # the sponsor's rows loaded once per sponsor; the same arithmetic as try_move otherwise
        r0 = np.float64(rest[s, 0])
        r1 = np.float64(rest[s, 1])
        r2 = np.float64(rest[s, 2])
        b0 = np.float64(pos[s, 0])
        b1 = np.float64(pos[s, 1])
        b2 = np.float64(pos[s, 2])
        # only the lanes whose neighbour had not moved (kernels.gather), in their listed order; the last
        # lane's bit, set only where the row overflows, sends the loop to the CSR lists after the row
        over = mask >> (LANES - 1)
        mask &= (np.int64(1) << (LANES - 1)) - 1
        while mask != 0:
            lane = lowest_bit(mask)
            mask &= mask - 1
            e = rows[LANES * s + lane]
            # stamp again: the mask was taken before the sponsors served since, and a link listed twice
            # may have moved e earlier in this very row
            if stamp[e] == gen or (has_fixed and fixed[e]):
                continue
            if has_dead or ms != 0:  # a lane's link is the row's CSR entry in the same place
                j = indptr[s] + lane
                if has_dead and not ealive[j]:
                    continue
                if ms != 0:
                    am = eamin[j]
                    ax = eamax[j]
                    be = ebeta[j]
            d0 = np.float64(rest[e, 0]) - r0
            d1 = np.float64(rest[e, 1]) - r1
            d2 = np.float64(rest[e, 2]) - r2
            a0 = abs(d0)
            a1 = abs(d1)
            a2 = abs(d2)
            # the clamps of kernels.boxes for the three axes, as selects (no branch on the data)
            x0 = pos[e, 0]
            x1 = pos[e, 1]
            x2 = pos[e, 2]
            lo, hi = _box_lo_hi(b0, d0, a0, a1 + a2, am, ax, be)
            f = np.float64(x0)
            c0 = pos.dtype.type(lo if f < lo else (hi if f > hi else f))
            lo, hi = _box_lo_hi(b1, d1, a1, a0 + a2, am, ax, be)
            f = np.float64(x1)
            c1 = pos.dtype.type(lo if f < lo else (hi if f > hi else f))
            lo, hi = _box_lo_hi(b2, d2, a2, a0 + a1, am, ax, be)
            f = np.float64(x2)
            c2 = pos.dtype.type(lo if f < lo else (hi if f > hi else f))
            # a move that rounds back to the stored value (float32) is no move
            if (c0 != x0) | (c1 != x1) | (c2 != x2):
                pos[e, 0] = c0
                pos[e, 1] = c1
                pos[e, 2] = c2
                stamp[e] = gen
                out_order[count] = e
                out_sponsor[count] = s
                count += 1
        if over:
            count = _fifo_overflow(
                rest, pos, indptr, indices, ealive, has_dead, eamin, eamax, ebeta, ms, fixed, has_fixed, stamp, gen,
                out_order, out_sponsor, count, s,
            )  # fmt: skip
    return count


@njit(cache=True)
def _fifo_overflow(
    rest, pos, indptr, indices, ealive, has_dead, eamin, eamax, ebeta, ms, fixed, has_fixed, stamp, gen, out_order,
    out_sponsor, count, s,
):  # fmt: skip
    """Sponsor s's neighbours from its sixteenth CSR entry on (those its row of sixteen has no lane for), in
    listed order, for _fifo_loop_3d; returns the new count."""
    for j in range(indptr[s] + LANES - 1, indptr[s + 1]):
        e = indices[j]
        if stamp[e] == gen or (has_dead and not ealive[j]) or (has_fixed and fixed[e]):
            continue
        if try_move(rest, pos, e, s, eamin[j * ms], eamax[j * ms], ebeta[j * ms]):
            stamp[e] = gen
            out_order[count] = e
            out_sponsor[count] = s
            count += 1
    return count


@njit(cache=True)
def _fifo_loop_nd(
    rest, pos, indptr, indices, ealive, has_dead, eamin, eamax, ebeta, ms, fixed, has_fixed, stamp, gen, out_order,
    out_sponsor, count,
):  # fmt: skip
    """_fifo_loop_3d for positions of any dimension, the box of each candidate from kernels.boxes."""
    n = pos.shape[0]
    owners = np.full(_RING, -1, dtype=np.int64)
    masks = np.zeros(_RING, dtype=np.int64)
    head = 0
    while head < count:
        if count == n:
            break
        # asked for ahead, and the ring kept, as in _fifo_loop_3d
        if head + 2 * _AHEAD < count:
            s2 = out_order[head + 2 * _AHEAD]
            prefetch(indptr, s2)
            prefetch(pos, s2)
            prefetch(rest, s2)
        if head + _AHEAD < count:
            s1 = out_order[head + _AHEAD]
            prefetch(indices, indptr[s1])
            prefetch(indices, indptr[s1 + 1] - 1)
        if head + _NEAR < count:
            s0 = out_order[head + _NEAR]
            first = indptr[s0]
            ahead = unmoved_mask(indices, first, min(indptr[s0 + 1] - first, LANES), stamp, gen)
            slot = (head + _NEAR) & (_RING - 1)
            owners[slot] = s0
            masks[slot] = ahead
            e0 = indices[first + lowest_bit(ahead)] if ahead != 0 else s0
            prefetch(pos, e0)
            prefetch(rest, e0)
        s = out_order[head]
        head += 1
        start = indptr[s]
        stop = indptr[s + 1]
        while start < stop:
            width = min(stop - start, LANES)
            if start == indptr[s] and owners[(head - 1) & (_RING - 1)] == s:
                mask = masks[(head - 1) & (_RING - 1)]
            else:
                mask = unmoved_mask(indices, start, width, stamp, gen)
            while mask != 0:
                j = start + lowest_bit(mask)
                mask &= mask - 1
                e = indices[j]
                if stamp[e] == gen or (has_dead and not ealive[j]) or (has_fixed and fixed[e]):
                    continue
                if try_move(rest, pos, e, s, eamin[j * ms], eamax[j * ms], ebeta[j * ms]):
                    stamp[e] = gen
                    out_order[count] = e
                    out_sponsor[count] = s
                    count += 1
            start += width
    return count


@njit(cache=True)
def _cascade_depth_first(
    rest,
    pos,
    indptr,
    indices,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    grabbed,
    targets,
    fixed,
    has_fixed,
    stamp,
    gen,
    q_entry,
    q_sponsor,
    out_order,
    out_sponsor,
):
    # 5.2.3 step 3.3 literally: a moved element's neighbours go to the front of the waiting list, so the
    # list is a stack. Each block is pushed in reverse so that it is served in its listed order (the
    # first neighbour first, as in the walk-through of Fig. 5.2).
    count = start_cascade(pos, grabbed, targets, fixed, has_fixed, stamp, gen, out_order, out_sponsor)
    if count < 0:
        return count
    top = 0
    for k in range(count - 1, -1, -1):
        g = out_order[k]
        for j in range(indptr[g + 1] - 1, indptr[g] - 1, -1):
            nb = indices[j]
            if stamp[nb] != gen and ealive[j] and not (has_fixed and fixed[nb]):
                q_entry[top] = j
                q_sponsor[top] = g
                top += 1
    while top > 0:
        top -= 1
        j = q_entry[top]
        s = q_sponsor[top]
        e = indices[j]
        if stamp[e] == gen:
            continue
        if not try_move(rest, pos, e, s, eamin[j * ms], eamax[j * ms], ebeta[j * ms]):
            continue
        stamp[e] = gen
        out_order[count] = e
        out_sponsor[count] = s
        count += 1
        for jj in range(indptr[e + 1] - 1, indptr[e] - 1, -1):
            nb = indices[jj]
            if stamp[nb] != gen and ealive[jj] and not (has_fixed and fixed[nb]):
                q_entry[top] = jj
                q_sponsor[top] = e
                top += 1
    return count


@njit(cache=True)
def _cascade_balanced(
    rest,
    pos,
    indptr,
    indices,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    grabbed,
    targets,
    fixed,
    has_fixed,
    stamp,
    gen,
    depth,
    q_entry,
    q_sponsor,
    q_depth,
    q_next,
    head,
    tail,
    out_order,
    out_sponsor,
):
    count = start_cascade(pos, grabbed, targets, fixed, has_fixed, stamp, gen, out_order, out_sponsor)
    if count < 0:
        return count
    n_entries = 0
    n_branches = 0
    for k in range(count):
        g = out_order[k]
        for j in range(indptr[g], indptr[g + 1]):
            nb = indices[j]
            if stamp[nb] != gen and ealive[j] and not (has_fixed and fixed[nb]):
                q_entry[n_entries] = j
                q_sponsor[n_entries] = g
                q_depth[n_entries] = 1
                q_next[n_entries] = -1
                head[n_branches] = n_entries
                tail[n_branches] = n_entries
                n_entries += 1
                n_branches += 1
    # head/tail hold the live branches compacted at the front; paused branches keep their queues
    limit = depth
    while n_branches > 0:
        live = 0
        for b in range(n_branches):
            h = head[b]
            t = tail[b]
            while h != -1 and q_depth[h] <= limit:
                j = q_entry[h]
                s = q_sponsor[h]
                dep = q_depth[h]
                h = q_next[h]
                if h == -1:
                    t = -1
                e = indices[j]
                if stamp[e] == gen:
                    continue
                if not try_move(rest, pos, e, s, eamin[j * ms], eamax[j * ms], ebeta[j * ms]):
                    continue
                stamp[e] = gen
                out_order[count] = e
                out_sponsor[count] = s
                count += 1
                for jj in range(indptr[e], indptr[e + 1]):
                    nb = indices[jj]
                    if stamp[nb] != gen and ealive[jj] and not (has_fixed and fixed[nb]):
                        q_entry[n_entries] = jj
                        q_sponsor[n_entries] = e
                        q_depth[n_entries] = dep + 1
                        q_next[n_entries] = -1
                        if t == -1:
                            h = n_entries
                        else:
                            q_next[t] = n_entries
                        t = n_entries
                        n_entries += 1
            if h != -1:
                head[live] = h
                tail[live] = t
                live += 1
        n_branches = live
        limit += depth
    return count


@njit(cache=True, inline="always")
def _heap_less(key, seq, i, j):
    """True when heap slot i should be served before slot j (bigger violation, then earlier push)."""
    if key[i] != key[j]:
        return key[i] > key[j]
    return seq[i] < seq[j]


@njit(cache=True, inline="always")
def _heap_swap(q_entry, q_sponsor, key, seq, i, j):
    q_entry[i], q_entry[j] = q_entry[j], q_entry[i]
    q_sponsor[i], q_sponsor[j] = q_sponsor[j], q_sponsor[i]
    key[i], key[j] = key[j], key[i]
    seq[i], seq[j] = seq[j], seq[i]


@njit(cache=True, inline="always")
def _heap_push(q_entry, q_sponsor, key, seq, size, j, s, v, sq):
    i = size
    q_entry[i] = j
    q_sponsor[i] = s
    key[i] = v
    seq[i] = sq
    while i > 0:
        p = (i - 1) // 2
        if _heap_less(key, seq, i, p):
            _heap_swap(q_entry, q_sponsor, key, seq, i, p)
            i = p
        else:
            break
    return size + 1


@njit(cache=True, inline="always")
def _heap_pop(q_entry, q_sponsor, key, seq, size):
    """Moves the top to slot `size - 1` and restores the heap on the rest; returns the new size."""
    size -= 1
    _heap_swap(q_entry, q_sponsor, key, seq, 0, size)
    i = 0
    while True:
        c = 2 * i + 1
        if c >= size:
            break
        if c + 1 < size and _heap_less(key, seq, c + 1, c):
            c += 1
        if _heap_less(key, seq, c, i):
            _heap_swap(q_entry, q_sponsor, key, seq, i, c)
            i = c
        else:
            break
    return size


@njit(cache=True)
def _cascade_schill(
    rest,
    pos,
    indptr,
    indices,
    ealive,
    eamin,
    eamax,
    ebeta,
    ms,
    grabbed,
    targets,
    fixed,
    has_fixed,
    stamp,
    gen,
    q_entry,
    q_sponsor,
    key,
    seq,
    out_order,
    out_sponsor,
):
    count = start_cascade(pos, grabbed, targets, fixed, has_fixed, stamp, gen, out_order, out_sponsor)
    if count < 0:
        return count
    size = 0
    pushed = 0
    for k in range(count):
        g = out_order[k]
        for j in range(indptr[g], indptr[g + 1]):
            nb = indices[j]
            if stamp[nb] != gen and ealive[j] and not (has_fixed and fixed[nb]):
                v = violation(rest, pos, nb, g, eamin[j * ms], eamax[j * ms], ebeta[j * ms])
                if v > 0.0:
                    size = _heap_push(q_entry, q_sponsor, key, seq, size, j, g, v, pushed)
                    pushed += 1
    while size > 0:
        size = _heap_pop(q_entry, q_sponsor, key, seq, size)
        j = q_entry[size]
        s = q_sponsor[size]
        e = indices[j]
        if stamp[e] == gen:
            continue
        if not try_move(rest, pos, e, s, eamin[j * ms], eamax[j * ms], ebeta[j * ms]):
            continue
        stamp[e] = gen
        out_order[count] = e
        out_sponsor[count] = s
        count += 1
        for jj in range(indptr[e], indptr[e + 1]):
            nb = indices[jj]
            if stamp[nb] != gen and ealive[jj] and not (has_fixed and fixed[nb]):
                v = violation(rest, pos, nb, e, eamin[jj * ms], eamax[jj * ms], ebeta[jj * ms])
                if v > 0.0:
                    size = _heap_push(q_entry, q_sponsor, key, seq, size, jj, e, v, pushed)
                    pushed += 1
    return count


# ----------------------------------------------------------------------------------------------------
# Python entry point


_START_ERRORS = {
    -1: "grabbed ids must be element ids in [0, N)",
    -2: "grabbed ids must be distinct",
    -3: "targets must be finite (no NaN or inf)",
}
_INT64 = np.dtype(np.int64)
_BOOL = np.dtype(np.bool_)


def _check_points(name, arr, n=None):
    if type(arr) is not np.ndarray or arr.ndim != 2 or arr.dtype.char not in "fd":
        got = arr.shape if isinstance(arr, np.ndarray) else type(arr).__name__
        raise ValueError(f"{name} must be a float32 or float64 array of shape (N, D), got {got}")
    if not arr.flags.c_contiguous:
        raise ValueError(f"{name} must be C-contiguous")
    if not 1 <= arr.shape[1] <= 3:
        raise ValueError(f"{name} must have D = 1, 2 or 3 columns, got {arr.shape[1]}")
    if n is not None and arr.shape[0] != n:
        raise ValueError(f"{name} must have {n} rows, got {arr.shape[0]}")


def _check_mesh(rest, pos, graph, amin, amax, beta) -> None:
    """The per-mesh arguments of cascade (skipped when a workspace has seen these very arrays); binds the
    materials to the graph (which keeps their CSR-order copy)."""
    n = pos.shape[0]
    if type(rest) is not np.ndarray or rest.shape != pos.shape or rest.dtype != pos.dtype:
        raise ValueError(
            f"rest must match pos in shape {pos.shape} and dtype {pos.dtype}, got "
            f"{getattr(rest, 'shape', type(rest).__name__)} {getattr(rest, 'dtype', '')}"
        )
    if not rest.flags.c_contiguous:
        raise ValueError("rest must be C-contiguous")
    if not isinstance(graph, Graph):
        raise ValueError(f"graph must be a Graph (build_graph), got {type(graph).__name__}")
    if graph.indptr.shape[0] != n + 1:
        raise ValueError(f"graph has {graph.indptr.shape[0] - 1} elements but pos has {n}")
    if amin is None and amax is None and beta is None:
        graph.kernel_args  # noqa: B018 - raises when no materials are bound
    else:
        graph.bind_materials(amin, amax, beta)


def _grab_arrays(grabbed, targets, fixed, n: int, dim: int, dtype):
    """cascade's grabbed ids (int64, 1-D, at least one), targets (K, D) of the positions' dtype and
    fixed mask (or none), as the kernels take them; ValueError on a wrong shape."""
    if type(grabbed) is not np.ndarray or grabbed.dtype != _INT64 or grabbed.ndim != 1:
        grabbed = np.ascontiguousarray(np.atleast_1d(np.asarray(grabbed)), dtype=np.int64)
        if grabbed.ndim != 1:
            raise ValueError("grabbed must be a 1-D array of element ids")
    k = grabbed.shape[0]
    if k < 1:
        raise ValueError("grabbed must hold at least one element id")
    if type(targets) is not np.ndarray or targets.dtype != dtype or not targets.flags.c_contiguous:
        targets = np.ascontiguousarray(targets, dtype=dtype)
    if targets.shape != (k, dim):
        if targets.ndim == 1 and k == 1 and targets.shape[0] == dim:
            targets = targets.reshape(1, dim)
        else:
            raise ValueError(f"targets must have shape ({k}, {dim}), got {targets.shape}")
    if fixed is None:
        fixed_arr, has_fixed = _NO_FIXED, False
    else:
        fixed_arr = fixed
        if type(fixed_arr) is not np.ndarray or fixed_arr.dtype != _BOOL or fixed_arr.shape != (n,):
            fixed_arr = np.ascontiguousarray(fixed, dtype=np.bool_)
            if fixed_arr.shape != (n,):
                raise ValueError(f"fixed must be a bool array of shape ({n},) or None, got {fixed_arr.shape}")
        has_fixed = True
    return grabbed, targets, fixed_arr, has_fixed


def _run_cascade(rest, pos, graph, kargs, grabbed, targets, fixed_arr, has_fixed, order, depth, parallel, ws) -> int:
    """One cascade in the chosen order's kernel; returns how many elements moved (negative: a start
    error, _START_ERRORS)."""
    gen = ws.next_generation()
    args = (rest, pos, *kargs, grabbed, targets, fixed_arr, has_fixed, ws.stamp, gen)
    if order == ORDER_BREADTH_FIRST:
        if parallel:
            count = waves.cascade_waves(*args, ws)  # type: ignore[call-arg]  # mypy lets *args take every parameter
        else:
            # 3-D meshes walk rows of sixteen and read the CSR lists only past a row's end or for a lane's
            # link data, so the graph's own arrays serve them; other dimensions walk an int32 copy
            rows = ws.rows16(graph) if pos.shape[1] == 3 else _NO_ROWS
            csr = kargs if rows.shape[0] else ws.narrow_csr(graph, kargs, padded=True)
            count = _cascade_fifo(
                rest, pos, csr[0], csr[1], rows, *csr[2:], grabbed, targets, fixed_arr, has_fixed, ws.stamp, gen,
                ws.out_order, ws.out_sponsor, graph.n_dead > 0,
            )  # fmt: skip
    elif order == ORDER_DEPTH_FIRST:
        count = _cascade_depth_first(*args, ws.q_entry, ws.q_sponsor, ws.out_order, ws.out_sponsor)
    elif order == ORDER_BALANCED:
        count = _cascade_balanced(
            *args,
            int(depth),
            ws.q_entry,
            ws.q_sponsor,
            ws.q_aux,
            ws.q_next,
            ws.branch_head,
            ws.branch_tail,
            ws.out_order,
            ws.out_sponsor,
        )
    else:
        count = _cascade_schill(*args, ws.q_entry, ws.q_sponsor, ws.q_key, ws.q_aux, ws.out_order, ws.out_sponsor)
    return count


def _parallel(order, depth, parallel, n: int) -> bool:
    """Check cascade's order and depth; whether it runs on numba's threads (parallel=None: where that wins)."""
    if order not in _ORDERS:
        raise ValueError(
            "order must be ORDER_BREADTH_FIRST (0), ORDER_BALANCED (1), ORDER_SCHILL (2) or ORDER_DEPTH_FIRST (3), "
            f"got {order!r}"
        )
    if order == ORDER_BALANCED and depth < 1:
        raise ValueError(f"depth must be >= 1, got {depth}")
    if parallel is None:
        # the size first, then the most threads numba may run: asking numba for its current thread count
        # costs about ten microseconds (a drag frame on a small patch costs not many more), and the rule
        # never picks the kernel for fewer threads where it does not for more
        parallel = (
            order == ORDER_BREADTH_FIRST
            and n >= waves.AUTO_MIN_ELEMENTS
            and waves.parallel_wins(n, numba.config.NUMBA_NUM_THREADS)
            and waves.parallel_wins(n, numba.get_num_threads())
        )
    if parallel and order != ORDER_BREADTH_FIRST:
        raise ValueError("parallel=True runs the breadth-first order only")
    return parallel


def _workspace_for(workspace, n: int, order, grabbed, graph) -> Workspace:
    """The workspace the cascade runs in (a temporary one without it), its queues sized for the order."""
    k = grabbed.shape[0]
    ws = workspace if workspace is not None else Workspace(n)
    if ws.n != n:
        raise ValueError(f"workspace was made for {ws.n} elements, mesh has {n}")
    if order == ORDER_BALANCED:
        if grabbed.min() < 0 or grabbed.max() >= n:
            raise ValueError(_START_ERRORS[-1].replace("N)", f"{n})"))
        branches = int((graph.indptr[grabbed + 1] - graph.indptr[grabbed]).sum())
        ws.ensure(graph.indices.shape[0] + k, order, branches)
    elif order in (ORDER_SCHILL, ORDER_DEPTH_FIRST):
        ws.ensure(graph.indices.shape[0] + k, order)
    return ws


def cascade(
    rest,
    pos,
    graph: Graph,
    amin,
    amax,
    beta,
    grabbed,
    targets,
    fixed=None,
    order=ORDER_BREADTH_FIRST,
    workspace: Workspace | None = None,
    depth: int = 2,
    copy: bool = True,
    parallel: bool | None = False,
):
    """Move `grabbed` to `targets` and propagate the move through the mesh (5.2.3); pos changes in place.

    rest, pos: (N, D) float64, or both float32, D in 1..3. graph: from build_graph. amin/amax/beta:
    per-link arrays from material_arrays, bound to the graph on first use (and frozen: bind new arrays
    to change a material), or all None for the materials already bound. grabbed: int64 (K,) distinct
    ids; targets (K, D). fixed: bool (N,) anchors that never move (a grabbed anchor stays put and is
    left out of the result), or None. order: ORDER_BREADTH_FIRST, ORDER_DEPTH_FIRST, ORDER_BALANCED
    (branch depth `depth`) or ORDER_SCHILL. workspace: reuse one per mesh so a cascade costs what moves,
    not N (without one, a temporary of size N is made). parallel: breadth-first only, each wave's
    candidates checked on numba's threads (chainsim.systems.engine.kernels.waves); the result is the same. None
    lets the mesh size and numba's thread count decide (waves.parallel_wins); other orders run serially.

    Returns (order, sponsor_of_moved): the ids that moved in the order they moved (grabbed first), each
    once, and for each the element whose move made it move (-1 for grabbed). With copy=False these are
    views into the workspace, valid until its next cascade. Raises ValueError on bad arguments (pos is
    then left untouched).
    """
    chk = workspace.checked if workspace is not None else ()
    if (
        chk
        and chk[0] is pos
        and chk[1] is rest
        and chk[2] is graph
        and chk[3] is amin
        and chk[4] is amax
        and chk[5] is beta
        and chk[6] is graph.entry_amin
    ):
        kargs = chk[7]  # the very arrays checked before: interactive dragging skips straight to the move
    else:
        _check_points("pos", pos)
        _check_mesh(rest, pos, graph, amin, amax, beta)
        kargs = graph.kernel_args
        if workspace is not None and workspace.n == pos.shape[0]:
            workspace.checked = (pos, rest, graph, amin, amax, beta, graph.entry_amin, kargs)
    n, dim = pos.shape
    grabbed, targets, fixed_arr, has_fixed = _grab_arrays(grabbed, targets, fixed, n, dim, pos.dtype)
    parallel = _parallel(order, depth, parallel, n)
    ws = _workspace_for(workspace, n, order, grabbed, graph)
    count = _run_cascade(rest, pos, graph, kargs, grabbed, targets, fixed_arr, has_fixed, order, depth, parallel, ws)
    if count < 0:
        raise ValueError(_START_ERRORS[count].replace("N)", f"{n})"))
    moved = ws.out_order[:count]
    sponsors = ws.out_sponsor[:count]
    if copy:
        return moved.copy(), sponsors.copy()
    return moved, sponsors

"""Generalised ChainMail cascade (thesis 5.2): one kernel for curves, sheets and volumes in 1-, 2- or 3-D.

A cascade starts from a set of grabbed elements moved explicitly to targets (a tool's contact patch) and
spreads over the link graph: each candidate is checked against the valid box spanned by its sponsor's
new position and the REST link vector (5.2.2, 5.2.6). A candidate inside its box stays put and does not
propagate; one outside is clamped to the nearest point of the box, and its neighbours become candidates
with it as sponsor (5.2.3). Every element moves at most once per cascade (termination, 5.2.4), and an
element that has not moved may be checked again by a later sponsor.

Four orders for the waiting list:
  ORDER_BREADTH_FIRST  a plain queue (ORDER_FIFO is the same order under its older name);
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
nothing of size N is cleared or allocated per cascade.

Material limits are per link (arrays of length M), so inhomogeneous tissue is just different numbers on
different links. With d = rest[B] - rest[A] and o_a the sum of |d_b| over the other axes, the box on axis
a is [A*_a + amin|d_a| - beta o_a, A*_a + amax|d_a| + beta o_a] when d_a >= 0, mirrored when d_a < 0.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .graph import Graph

ORDER_BREADTH_FIRST = 0
ORDER_FIFO = ORDER_BREADTH_FIRST  # the older name of the same order
ORDER_BALANCED = 1
ORDER_SCHILL = 2
ORDER_DEPTH_FIRST = 3
_ORDERS = (ORDER_BREADTH_FIRST, ORDER_BALANCED, ORDER_SCHILL, ORDER_DEPTH_FIRST)

_NO_FIXED = np.zeros(1, dtype=np.bool_)
_GEN_LIMIT = 2**31 - 2  # int32 stamps: a quarter of a cache line less per element than int64


# ----------------------------------------------------------------------------------------------------
# materials


def material_arrays(n_links, alpha_min, alpha_max, beta, dtype=np.float64):
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
    at once. The output buffers are N long; the waiting-list buffers of the balanced and Schill orders
    are grown on demand (to the CSR size plus K) and then kept. The breadth-first order needs no queue.
    """

    def __init__(self, n: int):
        n = int(n)
        if n < 0:
            raise ValueError(f"workspace size must be >= 0, got {n}")
        self.n = n
        self.stamp = np.zeros(n, dtype=np.int32)
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

    def next_generation(self) -> int:
        self.gen += 1
        if self.gen >= _GEN_LIMIT:  # practically never; keeps stamps unambiguous
            self.stamp[:] = 0
            self.gen = 1
        return self.gen


def make_workspace(n: int) -> Workspace:
    """Workspace for a mesh of `n` elements; pass it to every cascade on that mesh."""
    return Workspace(n)


# ----------------------------------------------------------------------------------------------------
# kernels


@njit(cache=True, inline="always")
def _box(rest, pos, e, s, a, amin_l, amax_l, beta_l):
    """Valid interval of element e on axis a w.r.t. sponsor s (5.2.2, 5.2.6)."""
    d = np.float64(rest[e, a]) - np.float64(rest[s, a])
    ad = abs(d)
    o = 0.0
    for b in range(rest.shape[1]):
        if b != a:
            o += abs(np.float64(rest[e, b]) - np.float64(rest[s, b]))
    base = np.float64(pos[s, a])
    if d >= 0.0:
        lo = base + (amin_l * ad - beta_l * o)
        hi = base + (amax_l * ad + beta_l * o)
    else:
        lo = base - (amax_l * ad + beta_l * o)
        hi = base - (amin_l * ad - beta_l * o)
    return lo, hi


@njit(cache=True, inline="always")
def _clamp_axis(pos, e, a, base, d, o, amin_l, amax_l, beta_l):
    """Clamp coordinate a of e into its interval; True when the stored value changed."""
    ad = abs(d)
    if d >= 0.0:
        lo = base + (amin_l * ad - beta_l * o)
        hi = base + (amax_l * ad + beta_l * o)
    else:
        lo = base - (amax_l * ad + beta_l * o)
        hi = base - (amin_l * ad - beta_l * o)
    x = np.float64(pos[e, a])
    if x < lo:
        c = lo
    elif x > hi:
        c = hi
    else:
        return False
    old = pos[e, a]
    pos[e, a] = c  # cast to pos's dtype here, so float32 meshes compare what they store
    return pos[e, a] != old


@njit(cache=True, inline="always")
def _try_move(rest, pos, e, s, amin_l, amax_l, beta_l):
    """Clamp e into its box w.r.t. s, in place; True when e actually changed.

    Written out per dimension (same arithmetic, same order as _box) because this is the inner loop.
    """
    dim = pos.shape[1]
    if dim == 3:
        d0 = np.float64(rest[e, 0]) - np.float64(rest[s, 0])
        d1 = np.float64(rest[e, 1]) - np.float64(rest[s, 1])
        d2 = np.float64(rest[e, 2]) - np.float64(rest[s, 2])
        a0 = abs(d0)
        a1 = abs(d1)
        a2 = abs(d2)
        m0 = _clamp_axis(pos, e, 0, np.float64(pos[s, 0]), d0, a1 + a2, amin_l, amax_l, beta_l)
        m1 = _clamp_axis(pos, e, 1, np.float64(pos[s, 1]), d1, a0 + a2, amin_l, amax_l, beta_l)
        m2 = _clamp_axis(pos, e, 2, np.float64(pos[s, 2]), d2, a0 + a1, amin_l, amax_l, beta_l)
        return m0 or m1 or m2
    if dim == 2:
        d0 = np.float64(rest[e, 0]) - np.float64(rest[s, 0])
        d1 = np.float64(rest[e, 1]) - np.float64(rest[s, 1])
        m0 = _clamp_axis(pos, e, 0, np.float64(pos[s, 0]), d0, abs(d1), amin_l, amax_l, beta_l)
        m1 = _clamp_axis(pos, e, 1, np.float64(pos[s, 1]), d1, abs(d0), amin_l, amax_l, beta_l)
        return m0 or m1
    moved = False
    for a in range(dim):
        lo, hi = _box(rest, pos, e, s, a, amin_l, amax_l, beta_l)
        x = np.float64(pos[e, a])
        if x < lo:
            c = lo
        elif x > hi:
            c = hi
        else:
            continue
        old = pos[e, a]
        pos[e, a] = c
        if pos[e, a] != old:
            moved = True
    return moved


@njit(cache=True, inline="always")
def _violation(rest, pos, e, s, amin_l, amax_l, beta_l):
    """Euclidean distance from e to its box w.r.t. s (0 when inside)."""
    v = 0.0
    for a in range(pos.shape[1]):
        lo, hi = _box(rest, pos, e, s, a, amin_l, amax_l, beta_l)
        x = np.float64(pos[e, a])
        if x < lo:
            v += (lo - x) * (lo - x)
        elif x > hi:
            v += (x - hi) * (x - hi)
    return np.sqrt(v)


@njit(cache=True, inline="always")
def _start(pos, grabbed, targets, fixed, has_fixed, stamp, gen, out_order, out_sponsor):
    """Move the grabbed elements to their targets; returns how many moved (fixed ones stay), or a
    negative error code before anything moves: -1 id out of range, -2 repeated id, -3 target not finite.
    Checking here keeps the per-call Python cost independent of K."""
    n = pos.shape[0]
    for k in range(grabbed.shape[0]):
        g = grabbed[k]
        if g < 0 or g >= n:
            return -1
        if stamp[g] == gen:
            return -2
        stamp[g] = gen
        for a in range(pos.shape[1]):
            if not np.isfinite(targets[k, a]):
                return -3
    count = 0
    for k in range(grabbed.shape[0]):
        g = grabbed[k]
        if has_fixed and fixed[g]:
            continue
        for a in range(pos.shape[1]):
            pos[g, a] = targets[k, a]
        out_order[count] = g
        out_sponsor[count] = -1
        count += 1
    return count


@njit(cache=True)
def _cascade_fifo(
    rest,
    pos,
    indptr,
    indices,
    link,
    alive,
    amin,
    amax,
    beta,
    grabbed,
    targets,
    fixed,
    has_fixed,
    stamp,
    gen,
    out_order,
    out_sponsor,
):
    # With a FIFO waiting list the first queued entry for an element that violates its box is the one
    # that moves it: neither its position nor its (already moved) sponsor's changes before that entry
    # is served. So the move can be made when the entry is queued, and the output list doubles as the
    # queue: each element is queued at most once, like a breadth-first search.
    count = _start(pos, grabbed, targets, fixed, has_fixed, stamp, gen, out_order, out_sponsor)
    if count < 0:
        return count
    head = 0
    while head < count:
        s = out_order[head]
        head += 1
        for j in range(indptr[s], indptr[s + 1]):
            e = indices[j]
            if stamp[e] == gen or not alive[link[j]] or (has_fixed and fixed[e]):
                continue
            lk = link[j]
            if _try_move(rest, pos, e, s, amin[lk], amax[lk], beta[lk]):
                stamp[e] = gen
                out_order[count] = e
                out_sponsor[count] = s
                count += 1
    return count


@njit(cache=True)
def _cascade_depth_first(
    rest,
    pos,
    indptr,
    indices,
    link,
    alive,
    amin,
    amax,
    beta,
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
    count = _start(pos, grabbed, targets, fixed, has_fixed, stamp, gen, out_order, out_sponsor)
    if count < 0:
        return count
    top = 0
    for k in range(count - 1, -1, -1):
        g = out_order[k]
        for j in range(indptr[g + 1] - 1, indptr[g] - 1, -1):
            nb = indices[j]
            if stamp[nb] != gen and alive[link[j]] and not (has_fixed and fixed[nb]):
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
        lk = link[j]
        if not _try_move(rest, pos, e, s, amin[lk], amax[lk], beta[lk]):
            continue
        stamp[e] = gen
        out_order[count] = e
        out_sponsor[count] = s
        count += 1
        for jj in range(indptr[e + 1] - 1, indptr[e] - 1, -1):
            nb = indices[jj]
            if stamp[nb] != gen and alive[link[jj]] and not (has_fixed and fixed[nb]):
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
    link,
    alive,
    amin,
    amax,
    beta,
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
    count = _start(pos, grabbed, targets, fixed, has_fixed, stamp, gen, out_order, out_sponsor)
    if count < 0:
        return count
    n_entries = 0
    n_branches = 0
    for k in range(count):
        g = out_order[k]
        for j in range(indptr[g], indptr[g + 1]):
            nb = indices[j]
            if stamp[nb] != gen and alive[link[j]] and not (has_fixed and fixed[nb]):
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
                lk = link[j]
                if not _try_move(rest, pos, e, s, amin[lk], amax[lk], beta[lk]):
                    continue
                stamp[e] = gen
                out_order[count] = e
                out_sponsor[count] = s
                count += 1
                for jj in range(indptr[e], indptr[e + 1]):
                    nb = indices[jj]
                    if stamp[nb] != gen and alive[link[jj]] and not (has_fixed and fixed[nb]):
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
    link,
    alive,
    amin,
    amax,
    beta,
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
    count = _start(pos, grabbed, targets, fixed, has_fixed, stamp, gen, out_order, out_sponsor)
    if count < 0:
        return count
    size = 0
    pushed = 0
    for k in range(count):
        g = out_order[k]
        for j in range(indptr[g], indptr[g + 1]):
            nb = indices[j]
            if stamp[nb] != gen and alive[link[j]] and not (has_fixed and fixed[nb]):
                lk = link[j]
                v = _violation(rest, pos, nb, g, amin[lk], amax[lk], beta[lk])
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
        lk = link[j]
        if not _try_move(rest, pos, e, s, amin[lk], amax[lk], beta[lk]):
            continue
        stamp[e] = gen
        out_order[count] = e
        out_sponsor[count] = s
        count += 1
        for jj in range(indptr[e], indptr[e + 1]):
            nb = indices[jj]
            if stamp[nb] != gen and alive[link[jj]] and not (has_fixed and fixed[nb]):
                ll = link[jj]
                v = _violation(rest, pos, nb, e, amin[ll], amax[ll], beta[ll])
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
    """The per-mesh arguments of cascade (skipped when a workspace has seen these very arrays)."""
    n = pos.shape[0]
    if type(rest) is not np.ndarray or rest.shape != pos.shape or rest.dtype != pos.dtype:
        raise ValueError(
            f"rest must match pos in shape {pos.shape} and dtype {pos.dtype}, got "
            f"{getattr(rest, 'shape', type(rest).__name__)} {getattr(rest, 'dtype', '')}"
        )
    if not rest.flags.c_contiguous:
        raise ValueError("rest must be C-contiguous")
    if graph.indptr.shape[0] != n + 1:
        raise ValueError(f"graph has {graph.indptr.shape[0] - 1} elements but pos has {n}")
    m = graph.links.shape[0]
    for name, arr in (("amin", amin), ("amax", amax), ("beta", beta)):
        if type(arr) is not np.ndarray or arr.shape != (m,) or arr.dtype.char not in "fd":
            raise ValueError(f"{name} must be a per-link float array of shape ({m},) (see material_arrays)")


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
):
    """Move `grabbed` to `targets` and propagate the move through the mesh (5.2.3); pos changes in place.

    rest, pos: (N, D) float64, or both float32, D in 1..3. graph: from build_graph. amin/amax/beta:
    per-link arrays from material_arrays. grabbed: int64 (K,) distinct ids; targets (K, D). fixed:
    bool (N,) anchors that never move (a grabbed anchor stays put and is left out of the result), or
    None. order: ORDER_BREADTH_FIRST, ORDER_DEPTH_FIRST, ORDER_BALANCED (branch depth `depth`) or
    ORDER_SCHILL. workspace: reuse
    one per mesh so a cascade costs what moves, not N (without one, a temporary of size N is made).

    Returns (order, sponsor_of_moved): the ids that moved in the order they moved (grabbed first), each
    once, and for each the element whose move made it move (-1 for grabbed). With copy=False these are
    views into the workspace, valid until its next cascade. Raises ValueError on bad arguments (pos is
    then left untouched).
    """
    _check_points("pos", pos)
    n, dim = pos.shape
    chk = workspace.checked if workspace is not None else ()
    if not (
        chk
        and chk[0] is rest
        and chk[1] is graph
        and chk[2] is amin
        and chk[3] is amax
        and chk[4] is beta
        and rest.shape == pos.shape
        and rest.dtype == pos.dtype
    ):
        _check_mesh(rest, pos, graph, amin, amax, beta)
        if workspace is not None and workspace.n == n:
            workspace.checked = (rest, graph, amin, amax, beta)
    if type(grabbed) is not np.ndarray or grabbed.dtype != _INT64 or grabbed.ndim != 1:
        grabbed = np.ascontiguousarray(np.atleast_1d(np.asarray(grabbed)), dtype=np.int64)
        if grabbed.ndim != 1:
            raise ValueError("grabbed must be a 1-D array of element ids")
    k = grabbed.shape[0]
    if k < 1:
        raise ValueError("grabbed must hold at least one element id")
    if type(targets) is not np.ndarray or targets.dtype != pos.dtype or not targets.flags.c_contiguous:
        targets = np.ascontiguousarray(targets, dtype=pos.dtype)
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
    if order not in _ORDERS:
        raise ValueError(
            "order must be ORDER_BREADTH_FIRST (0), ORDER_BALANCED (1), ORDER_SCHILL (2) or ORDER_DEPTH_FIRST (3), "
            f"got {order!r}"
        )
    if order == ORDER_BALANCED and depth < 1:
        raise ValueError(f"depth must be >= 1, got {depth}")

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
    gen = ws.next_generation()
    args = (
        rest,
        pos,
        graph.indptr,
        graph.indices,
        graph.link,
        graph.alive,
        amin,
        amax,
        beta,
        grabbed,
        targets,
        fixed_arr,
        has_fixed,
        ws.stamp,
        gen,
    )
    if order == ORDER_BREADTH_FIRST:
        count = _cascade_fifo(*args, ws.out_order, ws.out_sponsor)
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
    if count < 0:
        raise ValueError(_START_ERRORS[count].replace("N)", f"{n})"))
    moved = ws.out_order[:count]
    sponsors = ws.out_sponsor[:count]
    if copy:
        return moved.copy(), sponsors.copy()
    return moved, sponsors

"""The breadth-first cascade through a uniform material with no freedom (alpha_min == alpha_max, beta 0),
replayed along a stored breadth-first tree instead of walking the neighbour lists again.

With alpha_min == alpha_max = a and beta = 0 the valid region of 5.2.2 shrinks to one point per link:
an element e checked against its sponsor s must sit at s* + a (r_e - r_s) on every axis, and it moves
(and propagates) exactly when it is not already there. When every element the cascade reaches moves on
its first check, as a pull from rest does, the breadth-first cascade (kernels.chainmail) is a plain
breadth-first search of the link graph from the grabbed elements: which element moves, in which order and
with which sponsor depends only on the graph, the grabbed ids and the fixed ones, not on any position.

So that search is stored once (the ids in order, for each the index of its sponsor in that order and the
CSR entry that reached it) and later cascades with the same graph, grabbed ids and fixed elements replay
it: one pass over the moved elements, reading each one's sponsor, instead of a pass over every CSR entry
of the reached region (about 14 per element on a tet mesh, most of them found already moved). Each
replayed element is checked exactly as the cascade checks it (the same float64 arithmetic, stored in
pos's dtype); the first one that would not move is where the real cascade's search leaves the stored
one, so the replay stops there and hands the cascade its exact state (what moved so far, the sponsor
being served and the entry it had reached) to go on as usual. The result is the breadth-first cascade's,
bit for bit, in every case (tested).

The tree belongs to a Workspace; the graph's `version` (bumped by every cut or revival), the grabbed ids
and the fixed mask (compared in the kernel) tell when it no longer applies.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .boxes import start_cascade

#: meshes smaller than this cascade the usual way: the tree's bookkeeping costs more than it saves there
#: (a full pull of a 125-element block: 5.6 us plain, 6.5 us replayed; 1000 elements: 24.5 against 12.3 us)
MIN_ELEMENTS = 512

REPLAY_DONE = 0
REPLAY_DIVERGED = 1
REPLAY_STALE = 2


def rigid_material(graph) -> float | None:
    """The common alpha of a uniform material with alpha_min == alpha_max and beta 0, else None."""
    if graph.mat_stride != 0:
        return None
    am = float(graph.entry_amin[0])
    beta = float(graph.entry_beta[0])
    # signed zeros excluded: with them the cascade's two bounds can differ in the sign of a zero
    if am != float(graph.entry_amax[0]) or beta != 0.0 or math.copysign(1.0, beta) < 0 or math.copysign(1.0, am) < 0:
        return None
    return am


class RigidTree:
    """A stored breadth-first tree of one mesh (see the module docstring), and the key it holds for."""

    def __init__(self):
        self.graph = None
        self.version = -1
        self.grabbed = np.empty(0, dtype=np.int64)
        self.fixed = np.zeros(1, dtype=np.bool_)
        self.has_fixed = False
        self.order = np.empty(0, dtype=np.int32)
        self.spos = np.empty(0, dtype=np.int32)
        self.entry = np.empty(0, dtype=np.int32)
        self.count = 0
        self.start = 0
        # the last call that had no tree: a tree is built when the next call repeats it (a drag), so a
        # one-off cascade never pays for building one
        self.seen = None

    def holds_for(self, graph, grabbed) -> bool:
        """Whether the tree was built for this graph (and link state) and these grabbed ids; the fixed
        mask is compared by the replay kernel."""
        return (
            self.graph is graph
            and self.version == graph.version
            and self.grabbed.shape == grabbed.shape
            and bool(np.array_equal(self.grabbed, grabbed))
        )

    def want(self, graph, grabbed) -> bool:
        """Record a call without a tree; True when the previous one was the same move (build now)."""
        key = (graph, graph.version, grabbed.tobytes())
        again = self.seen is not None and self.seen[0] is graph and self.seen[1:] == key[1:]
        self.seen = key
        return again

    def build(self, graph, grabbed, fixed, has_fixed, stamp, gen) -> None:
        n = graph.indptr.shape[0] - 1
        idx = np.int32 if graph.indices.shape[0] < 2**31 - 1 else np.int64
        if self.order.shape[0] < n or self.order.dtype != idx:
            self.order = np.empty(n, dtype=idx)
            self.spos = np.empty(n, dtype=idx)
            self.entry = np.empty(n, dtype=idx)
        count, start = _bfs_tree(
            graph.indptr, graph.indices, graph.entry_alive, grabbed, fixed, has_fixed, stamp, gen, self.order,
            self.spos, self.entry,
        )  # fmt: skip
        self.graph = graph
        self.version = graph.version
        self.grabbed = grabbed.copy()
        self.has_fixed = bool(has_fixed)
        self.fixed = fixed.copy() if has_fixed else np.zeros(1, dtype=np.bool_)
        self.count = int(count)
        self.start = int(start)
        self.seen = None


@njit(cache=True)
def _bfs_tree(indptr, indices, ealive, grabbed, fixed, has_fixed, stamp, gen, order, spos, entry):
    """The breadth-first search the cascade makes when every element it reaches moves: the same skips
    (moved, cut link, fixed element) in the same order. Returns (count, how many grabbed ones start it)."""
    count = 0
    for k in range(grabbed.shape[0]):
        stamp[grabbed[k]] = gen
    for k in range(grabbed.shape[0]):
        g = grabbed[k]
        if has_fixed and fixed[g]:
            continue
        order[count] = g
        spos[count] = -1
        entry[count] = -1
        count += 1
    start = count
    head = 0
    while head < count:
        s = order[head]
        for j in range(indptr[s], indptr[s + 1]):
            e = indices[j]
            if stamp[e] == gen or not ealive[j] or (has_fixed and fixed[e]):
                continue
            stamp[e] = gen
            order[count] = e
            spos[count] = head
            entry[count] = j
            count += 1
        head += 1
    return count, start


@njit(cache=True)
def replay(
    rest,
    pos,
    grabbed,
    targets,
    fixed,
    has_fixed,
    stamp,
    gen,
    out_order,
    out_sponsor,
    alpha,
    t_order,
    t_spos,
    t_entry,
    t_count,
    t_start,
    t_grabbed,
    t_fixed,
    t_has_fixed,
):
    """The cascade along the stored tree. Returns (status, count, head, j0): REPLAY_DONE with the final
    count; REPLAY_DIVERGED with the cascade's state to go on from (out_order[:count] moved and stamped, the
    sponsor at out_order[head] next, from CSR entry j0); REPLAY_STALE (nothing done: the grabbed ids or the
    fixed mask differ from the tree's); or a negative status, start_cascade's error code."""
    if grabbed.shape[0] != t_grabbed.shape[0] or has_fixed != t_has_fixed:
        return REPLAY_STALE, 0, 0, -1
    for k in range(grabbed.shape[0]):
        if grabbed[k] != t_grabbed[k]:
            return REPLAY_STALE, 0, 0, -1
    if has_fixed:
        for i in range(fixed.shape[0]):
            if fixed[i] != t_fixed[i]:
                return REPLAY_STALE, 0, 0, -1
    count = start_cascade(pos, grabbed, targets, fixed, has_fixed, stamp, gen, out_order, out_sponsor)
    if count < 0:
        return count, 0, 0, -1
    if count != t_start:  # cannot happen with the same grabbed ids and fixed mask; kept as a guard
        return REPLAY_DIVERGED, count, 0, -1
    dim = pos.shape[1]
    for k in range(count, t_count):
        p = t_spos[k]
        s = out_order[p]
        e = t_order[k]
        # the cascade's box of e against s, [lo, hi] with lo == hi: s* + a|d| for d >= 0, s* - a|d| below
        # (kernels.chainmail's bounds with beta = +0 and a >= +0 are exactly these, bit for bit)
        moved = False
        for a in range(dim):
            d = np.float64(rest[e, a]) - np.float64(rest[s, a])
            b = np.float64(pos[s, a])
            v = b + alpha * abs(d) if d >= 0.0 else b - alpha * abs(d)
            x = np.float64(pos[e, a])
            if x < v or x > v:
                old = pos[e, a]
                pos[e, a] = v
                if pos[e, a] != old:
                    moved = True
        if not moved:
            # the real cascade leaves e where it is here and serves s's next entries: hand over its state
            for q in range(k):
                stamp[out_order[q]] = gen
            return REPLAY_DIVERGED, k, p, t_entry[k] + 1
        out_order[k] = e
        out_sponsor[k] = s
    return REPLAY_DONE, t_count, 0, -1

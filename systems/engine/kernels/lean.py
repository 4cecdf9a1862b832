"""The lean cascade: the smallest breadth-first Generalised ChainMail cascade over plain CSR arrays.

A yardstick for the benchmarks, not an engine feature: one grabbed element, one material for every
link, no cut links, no anchors, float64 positions, no argument checks. It is what the production
kernel (kernels.chainmail, breadth-first order) reduces to when none of those features is used, so on
such a mesh both must give the same result (tested), and `chainsim bench chainmail` times both in the
same run and prints their ratio: the price of the features, measured rather than guessed.

The box is the one of 5.2.2 / 5.2.6 (see kernels.boxes), written out for three axes or fewer.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _clamp(x, base, d, ad, o, amin, amax, beta):
    """x clamped into [lo, hi], the interval of 5.2.2 on one axis (mirrored for d < 0)."""
    if d >= 0.0:
        lo = base + (amin * ad - beta * o)
        hi = base + (amax * ad + beta * o)
    else:
        lo = base - (amax * ad + beta * o)
        hi = base - (amin * ad - beta * o)
    if x < lo:
        return lo
    if x > hi:
        return hi
    return x


@njit(cache=True)
def lean_cascade(rest, pos, indptr, indices, grab, target, amin, amax, beta, moved, order):
    """Move element `grab` to `target` (D,) and cascade breadth-first; pos changes in place.

    moved: (N,) flags, all 0 on entry (set for the elements that move; LeanWorkspace clears them after).
    order: (N,) receives the moved ids in the order they moved. Returns how many moved.
    """
    dim = pos.shape[1]
    for a in range(dim):
        pos[grab, a] = target[a]
    moved[grab] = 1
    order[0] = grab
    count = 1
    head = 0
    while head < count:
        s = order[head]
        head += 1
        if dim == 3:
            # the common case written out: rows of s loaded once, three axes inline
            r0 = rest[s, 0]
            r1 = rest[s, 1]
            r2 = rest[s, 2]
            p0 = pos[s, 0]
            p1 = pos[s, 1]
            p2 = pos[s, 2]
            for j in range(indptr[s], indptr[s + 1]):
                e = indices[j]
                if moved[e]:
                    continue
                d0 = rest[e, 0] - r0
                d1 = rest[e, 1] - r1
                d2 = rest[e, 2] - r2
                a0 = abs(d0)
                a1 = abs(d1)
                a2 = abs(d2)
                c0 = _clamp(pos[e, 0], p0, d0, a0, a1 + a2, amin, amax, beta)
                c1 = _clamp(pos[e, 1], p1, d1, a1, a0 + a2, amin, amax, beta)
                c2 = _clamp(pos[e, 2], p2, d2, a2, a0 + a1, amin, amax, beta)
                if c0 != pos[e, 0] or c1 != pos[e, 1] or c2 != pos[e, 2]:
                    pos[e, 0] = c0
                    pos[e, 1] = c1
                    pos[e, 2] = c2
                    moved[e] = 1
                    order[count] = e
                    count += 1
            continue
        for j in range(indptr[s], indptr[s + 1]):
            e = indices[j]
            if moved[e]:
                continue
            changed = False
            for a in range(dim):
                d = rest[e, a] - rest[s, a]
                o = 0.0
                for b in range(dim):
                    if b != a:
                        o += abs(rest[e, b] - rest[s, b])
                c = _clamp(pos[e, a], pos[s, a], d, abs(d), o, amin, amax, beta)
                if c != pos[e, a]:
                    pos[e, a] = c
                    changed = True
            if changed:
                moved[e] = 1
                order[count] = e
                count += 1
    return count


@njit(cache=True)
def _clear(moved, order, count):
    for k in range(count):
        moved[order[k]] = 0


class LeanWorkspace:
    """Scratch for lean cascades on one mesh: flags set by a cascade are cleared after it (cost follows
    what moved)."""

    def __init__(self, n: int):
        self.moved = np.zeros(n, dtype=np.uint8)
        self.order = np.empty(n, dtype=np.int64)


def lean_move(rest, pos, indptr, indices, grab: int, target, amin: float, amax: float, beta: float, ws) -> int:
    """One lean cascade (see the module docstring); returns how many elements moved."""
    count = lean_cascade(rest, pos, indptr, indices, grab, target, amin, amax, beta, ws.moved, ws.order)
    _clear(ws.moved, ws.order, count)
    return count

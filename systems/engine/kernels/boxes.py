"""The valid region of a link (thesis 5.2.2, 5.2.6) and the move of an element into it: the primitives the
cascade kernels share (kernels.chainmail for the sequential orders, kernels.waves for the level-parallel
one), plus the start of every cascade (the grabbed elements put at their targets).

With d = rest[e] - rest[s] and o_a the sum of |d_b| over the other axes, the box of e on axis a after its
sponsor s moved is [s*_a + amin|d_a| - beta o_a, s*_a + amax|d_a| + beta o_a] when d_a >= 0, mirrored when
d_a < 0. Coordinates are compared in float64 and stored in pos's dtype.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def box(rest, pos, e, s, a, amin_l, amax_l, beta_l):
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
def clamp_axis(pos, e, a, base, d, o, amin_l, amax_l, beta_l):
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
def try_move_to(rest, pos, e, s, amin_l, amax_l, beta_l, dst, row):
    """Clamp dst[row] (holding e's position) into e's box w.r.t. s; True when a stored value changed.

    dst is pos itself (row = e) for the sequential cascades, or a buffer the level-parallel one writes
    first and copies later; the arithmetic is the same either way. Written out per dimension (same
    arithmetic, same order as box) because this is the inner loop.
    """
    dim = pos.shape[1]
    if dim == 3:
        d0 = np.float64(rest[e, 0]) - np.float64(rest[s, 0])
        d1 = np.float64(rest[e, 1]) - np.float64(rest[s, 1])
        d2 = np.float64(rest[e, 2]) - np.float64(rest[s, 2])
        a0 = abs(d0)
        a1 = abs(d1)
        a2 = abs(d2)
        m0 = clamp_axis(dst, row, 0, np.float64(pos[s, 0]), d0, a1 + a2, amin_l, amax_l, beta_l)
        m1 = clamp_axis(dst, row, 1, np.float64(pos[s, 1]), d1, a0 + a2, amin_l, amax_l, beta_l)
        m2 = clamp_axis(dst, row, 2, np.float64(pos[s, 2]), d2, a0 + a1, amin_l, amax_l, beta_l)
        return m0 or m1 or m2
    if dim == 2:
        d0 = np.float64(rest[e, 0]) - np.float64(rest[s, 0])
        d1 = np.float64(rest[e, 1]) - np.float64(rest[s, 1])
        m0 = clamp_axis(dst, row, 0, np.float64(pos[s, 0]), d0, abs(d1), amin_l, amax_l, beta_l)
        m1 = clamp_axis(dst, row, 1, np.float64(pos[s, 1]), d1, abs(d0), amin_l, amax_l, beta_l)
        return m0 or m1
    moved = False
    for a in range(dim):
        lo, hi = box(rest, pos, e, s, a, amin_l, amax_l, beta_l)
        x = np.float64(dst[row, a])
        if x < lo:
            c = lo
        elif x > hi:
            c = hi
        else:
            continue
        old = dst[row, a]
        dst[row, a] = c
        if dst[row, a] != old:
            moved = True
    return moved


@njit(cache=True, inline="always")
def try_move(rest, pos, e, s, amin_l, amax_l, beta_l):
    """Clamp e into its box w.r.t. s, in place; True when e actually changed."""
    return try_move_to(rest, pos, e, s, amin_l, amax_l, beta_l, pos, e)


@njit(cache=True, inline="always")
def violation(rest, pos, e, s, amin_l, amax_l, beta_l):
    """Euclidean distance from e to its box w.r.t. s (0 when inside)."""
    v = 0.0
    for a in range(pos.shape[1]):
        lo, hi = box(rest, pos, e, s, a, amin_l, amax_l, beta_l)
        x = np.float64(pos[e, a])
        if x < lo:
            v += (lo - x) * (lo - x)
        elif x > hi:
            v += (x - hi) * (x - hi)
    return np.sqrt(v)


@njit(cache=True, inline="always")
def start_cascade(pos, grabbed, targets, fixed, has_fixed, stamp, gen, out_order, out_sponsor):
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

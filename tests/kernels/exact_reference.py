"""Plain numpy reference for the exact-limit pass, written from the definitions (per-axis difference
constraints of 5.2.2, their lattice closures and reachable boxes), not from the kernel: whole-mesh
Bellman-Ford sweeps, no regions, no queues, no early stops."""

from __future__ import annotations

import numpy as np


def link_terms(rest, links, alive, amin, amax, beta):
    """(i, j, centre (M, D), half-width (M, D)) of every live link: x_j - x_i must lie within
    centre +- half-width on each axis (the interval of 5.2.2 written about its middle)."""
    live = np.flatnonzero(alive)
    i, j = links[live, 0], links[live, 1]
    d = rest[j] - rest[i]
    ad = np.abs(d)
    other = ad.sum(axis=1, keepdims=True) - ad
    lo_, hi_, b = amin[live, None], amax[live, None], beta[live, None]
    return i, j, 0.5 * (lo_ + hi_) * d, 0.5 * (hi_ - lo_) * ad + b * other, ad.sum(axis=1)


def close(x, i, j, c, w, l1, pinned, down, eps_rel=1e-11, sweeps=100_000):
    """The closure of x on one axis: lowering (down) or raising elements other than pinned ones until
    every link such moves can fix holds; Jacobi Bellman-Ford sweeps. Returns (x, blocked: a violated
    link only a pin's move could fix)."""
    x = x.copy()
    eps = eps_rel * l1
    for _ in range(sweeps):
        u = x[j] - x[i]
        above = u - (c + w)  # > 0: j too high relative to i
        below = (c - w) - u  # > 0: j too low
        new = x.copy()
        if down:
            # lower j to x_i + c + w, or lower i to x_j - c + w
            m = above > eps
            np.minimum.at(new, j[m], (x[i] + c + w)[m])
            m = below > eps
            np.minimum.at(new, i[m], (x[j] - c + w)[m])
        else:
            m = above > eps
            np.maximum.at(new, i[m], (x[j] - c - w)[m])
            m = below > eps
            np.maximum.at(new, j[m], (x[i] + c - w)[m])
        new[pinned] = x[pinned]
        if np.array_equal(new, x):
            break
        x = new
    u = x[j] - x[i]
    bad = ((u - (c + w)) > 10 * eps + 1e-12) | (((c - w) - u) > 10 * eps + 1e-12)
    return x, bool(bad.any())


def reach(x, i, j, c, w, pins, g):
    """[L, U] for element g on one axis: U = min over pins p of x_p + dist(p -> g), L = max over pins of
    x_p - dist(g -> p), dist the shortest path with link bounds as weights (Bellman-Ford, whole mesh)."""
    n = len(x)
    up = np.full(n, np.inf)
    lo = np.full(n, -np.inf)
    up[pins] = x[pins]
    lo[pins] = x[pins]
    for _ in range(n + 1):
        # x_j <= x_i + (c + w) and x_i <= x_j - (c - w)
        new_up = up.copy()
        np.minimum.at(new_up, j, up[i] + c + w)
        np.minimum.at(new_up, i, up[j] - c + w)
        # x_j >= x_i + (c - w) and x_i >= x_j - (c + w)
        new_lo = lo.copy()
        np.maximum.at(new_lo, j, lo[i] + c - w)
        np.maximum.at(new_lo, i, lo[j] - c - w)
        new_up[pins] = x[pins]
        new_lo[pins] = x[pins]
        if np.array_equal(new_up, up) and np.array_equal(new_lo, lo):
            break
        up, lo = new_up, new_lo
    return lo[g], up[g]


def ref_exact(rest, x0, links, alive, amin, amax, beta, grabbed, targets, fixed=None):
    """Every link inside its box, pins (fixed and grabbed) kept, each axis closed first in the direction
    of the pull, then the other way; a grabbed element whose target the fixed ones make unreachable is
    first clamped into its reachable box (several in the order given). Returns (positions, shortfall)."""
    n, dim = x0.shape
    fixed = np.zeros(n, bool) if fixed is None else np.asarray(fixed, bool)
    grabbed = np.asarray(grabbed)
    targets = np.asarray(targets, dtype=np.float64).reshape(len(grabbed), dim)
    free = ~fixed[grabbed]
    i, j, c, w, l1 = link_terms(rest, links, alive, amin, amax, beta)
    pull = (targets[free] - rest[grabbed[free]]).sum(axis=0) if free.any() else np.zeros(dim)
    x = x0.astype(np.float64).copy()
    pinned = fixed.copy()
    pinned[grabbed] = True

    def walks(x):
        out = x.copy()
        blocked = False
        for a in range(dim):
            first = pull[a] < 0.0
            y, _ = close(out[:, a], i, j, c[:, a], w[:, a], l1, pinned, first)
            y, b = close(y, i, j, c[:, a], w[:, a], l1, pinned, not first)
            out[:, a] = y
            blocked |= b
        return out, blocked

    result, blocked = walks(x)
    if blocked and free.any():
        # settle the grabbed elements in order, each against the fixed ones and those settled before
        x = x0.astype(np.float64).copy()
        pins = fixed.copy()
        for k, g in enumerate(grabbed):
            if fixed[g]:
                continue
            for a in range(dim):
                if pins.any():
                    lo, hi = reach(x[:, a], i, j, c[:, a], w[:, a], np.flatnonzero(pins), g)
                    x[g, a] = min(max(targets[k, a], lo), hi)
            pins[g] = True
        result, _ = walks(x)
    short = np.linalg.norm(targets[free] - result[grabbed[free]], axis=1)
    return result, float(short.max()) if short.size else 0.0

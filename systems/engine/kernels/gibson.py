"""Gibson's ChainMail on rectilinear grids (thesis 4.2), the baseline, and its relative-limit form (4.3).

Elements sit on an nx x ny (x nz) grid, element (i, j[, k]) having id i + nx*(j + ny*k) (the layout of
chainsim.systems.engine.meshgen.grid);
each is linked to its left/right (x), bottom/top (y) and back/front (z) neighbours.

Propagation uses one candidate list per direction, as 4.2.2 describes: the grabbed element puts every
neighbour on the list of its direction; a moved x-list candidate adds its next x neighbour (same
direction) and its y and z neighbours; a moved y-list candidate adds its next y neighbour and its z
neighbours; a moved z-list candidate adds only its next z neighbour. Lists are emptied in the order
right, left, top, bottom, front, back. Every element is therefore reached along exactly one path
(x first, then y, then z), so each is considered at most once without any flag.

A candidate C checked against its sponsor A across a link along axis a, in direction s = +1 or -1:
  along a:       s (C_a - A_a) must lie in [min_dx[a], max_dx[a]]        (compression / stretch)
  other axes b:  |C_b - A_b| must be at most max_shear[a]                  (shear)
C is clamped to the nearest allowed point; only a candidate that actually moved propagates.
In the relative form (4.3) the three limits are material factors multiplied by the rest distance
|rest[C] - rest[A]| of that link, so non-uniform grid spacing gives a consistent softness.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .graph import fixed_mask

# list order and (axis, sign) of each direction: right, left, top, bottom, front, back
_DIR_AXIS = np.array([0, 0, 1, 1, 2, 2], dtype=np.int64)
_DIR_SIGN = np.array([1, -1, 1, -1, 1, -1], dtype=np.int64)


@njit(cache=True)
def _neighbour(idx, axis, sign, nx, ny, nz):
    """Id of the grid neighbour of idx along axis in direction sign, or -1 outside the grid."""
    i = idx % nx
    j = (idx // nx) % ny
    k = idx // (nx * ny)
    if axis == 0:
        i += sign
        if i < 0 or i >= nx:
            return -1
    elif axis == 1:
        j += sign
        if j < 0 or j >= ny:
            return -1
    else:
        k += sign
        if k < 0 or k >= nz:
            return -1
    return i + nx * (j + ny * k)


@njit(cache=True)
def _push(lst, cand, spons, nxt, head, tail, n_used, c, s):
    if n_used >= cand.shape[0]:
        return n_used
    cand[n_used] = c
    spons[n_used] = s
    nxt[n_used] = -1
    if tail[lst] == -1:
        head[lst] = n_used
    else:
        nxt[tail[lst]] = n_used
    tail[lst] = n_used
    return n_used + 1


@njit(cache=True)
def _grid_kernel(
    pos,
    rest,
    relative,
    nx,
    ny,
    nz,
    grabbed,
    target,
    lim_min,
    lim_max,
    lim_shear,
    fixed,
    has_fixed,
    dir_axis,
    dir_sign,
    out,
):
    dim = pos.shape[1]
    n_dirs = 2 * dim
    n = pos.shape[0]
    cand = np.empty(n, dtype=np.int64)
    spons = np.empty(n, dtype=np.int64)
    nxt = np.empty(n, dtype=np.int64)
    head = np.full(6, -1, dtype=np.int64)
    tail = np.full(6, -1, dtype=np.int64)
    n_used = 0
    count = 0
    if has_fixed and fixed[grabbed]:
        return 0
    for a in range(dim):
        pos[grabbed, a] = target[a]
    out[count] = grabbed
    count += 1
    for d in range(n_dirs):
        nb = _neighbour(grabbed, dir_axis[d], dir_sign[d], nx, ny, nz)
        if nb >= 0 and not (has_fixed and fixed[nb]):
            n_used = _push(d, cand, spons, nxt, head, tail, n_used, nb, grabbed)
    for d in range(n_dirs):
        ax = dir_axis[d]
        sg = dir_sign[d]
        while head[d] != -1:
            h = head[d]
            head[d] = nxt[h]
            if head[d] == -1:
                tail[d] = -1
            c = cand[h]
            s = spons[h]
            scale = 1.0
            if relative:
                dist2 = 0.0
                for b in range(dim):
                    dd = rest[c, b] - rest[s, b]
                    dist2 += dd * dd
                scale = np.sqrt(dist2)
            lo = lim_min[ax] * scale
            hi = lim_max[ax] * scale
            sh = lim_shear[ax] * scale
            moved = False
            for b in range(dim):
                x = pos[c, b]
                base = pos[s, b]
                if b == ax:
                    along = sg * (x - base)
                    if along < lo:
                        newv = base + sg * lo
                    elif along > hi:
                        newv = base + sg * hi
                    else:
                        continue
                else:
                    diff = x - base
                    if diff < -sh:
                        newv = base - sh
                    elif diff > sh:
                        newv = base + sh
                    else:
                        continue
                pos[c, b] = newv
                if pos[c, b] != x:
                    moved = True
            if not moved:
                continue
            out[count] = c
            count += 1
            # same-direction neighbour, then the lists of later axes (4.2.2)
            for d2 in range(n_dirs):
                ax2 = dir_axis[d2]
                if (ax2 == ax and dir_sign[d2] == sg) or ax2 > ax:
                    nb = _neighbour(c, ax2, dir_sign[d2], nx, ny, nz)
                    if nb >= 0 and not (has_fixed and fixed[nb]):
                        n_used = _push(d2, cand, spons, nxt, head, tail, n_used, nb, c)
    return count


def _limits(name, value, dim):
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(dim, float(arr))
    if arr.shape != (dim,):
        raise ValueError(f"{name} must be a scalar or one value per grid axis ({dim},), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr}")
    full = np.zeros(3)
    full[:dim] = arr
    return full


def _prepare(pos, shape, grabbed, target, fixed):
    shape = tuple(int(s) for s in shape)
    if len(shape) not in (2, 3) or min(shape) < 1:
        raise ValueError(f"shape must be (nx, ny) or (nx, ny, nz) with positive sizes, got {shape}")
    dim = len(shape)
    n = int(np.prod(shape))
    if not isinstance(pos, np.ndarray) or pos.dtype != np.float64 or pos.shape != (n, dim):
        raise ValueError(f"pos must be a float64 array of shape ({n}, {dim}) for grid shape {shape}")
    if not pos.flags.c_contiguous:
        raise ValueError("pos must be C-contiguous")
    grabbed = int(grabbed)
    if not 0 <= grabbed < n:
        raise ValueError(f"grabbed must be an element id in [0, {n}), got {grabbed}")
    target = np.asarray(target, dtype=np.float64).reshape(-1)
    if target.shape != (dim,) or not np.all(np.isfinite(target)):
        raise ValueError(f"target must be {dim} finite coordinates, got {target}")
    fixed_arr, has_fixed = fixed_mask(fixed, n)
    nx, ny = shape[0], shape[1]
    nz = shape[2] if dim == 3 else 1
    return dim, n, nx, ny, nz, grabbed, target, fixed_arr, has_fixed


def gibson_grid_move(pos, shape, grabbed, target, min_dx, max_dx, max_shear, fixed=None, return_moved=False):
    """Gibson's ChainMail (4.2.2) with absolute limits: move `grabbed` to `target`, propagate, in place.

    pos: float64 (N, D) with D = len(shape) = 2 or 3. grabbed: one element id; target: (D,).
    min_dx, max_dx, max_shear: scalars or one value per grid axis (the limits for links along that
    axis, e.g. (minDx, minDy)); max_shear[a] bounds the sideways offset across an axis-a link.
    fixed: bool (N,) elements that never move (a fixed grabbed element makes the call a no-op).
    Returns the number of moved elements (grabbed included), or (n_moved, moved_ids) when
    return_moved is True, moved_ids in the order they moved.
    """
    dim, n, nx, ny, nz, grabbed, target, fixed_arr, has_fixed = _prepare(pos, shape, grabbed, target, fixed)
    lo, hi, sh = (_limits("min_dx", min_dx, dim), _limits("max_dx", max_dx, dim), _limits("max_shear", max_shear, dim))
    if np.any(lo[:dim] > hi[:dim]) or np.any(sh[:dim] < 0):
        raise ValueError(f"need min_dx <= max_dx and max_shear >= 0, got {min_dx}, {max_dx}, {max_shear}")
    out = np.empty(n, dtype=np.int64)
    count = _grid_kernel(
        pos, pos, False, nx, ny, nz, grabbed, target, lo, hi, sh, fixed_arr, has_fixed, _DIR_AXIS, _DIR_SIGN, out
    )
    return (count, out[:count].copy()) if return_moved else count


def relative_grid_move(
    pos, rest, shape, grabbed, target, min_rel, max_rel, max_rel_shear, fixed=None, return_moved=False
):
    """Gibson's ChainMail with limits relative to each link's rest length (4.3), for non-uniform grids.

    As gibson_grid_move, but a link of rest length L along axis a allows an along-axis offset in
    [min_rel[a] L, max_rel[a] L] and a sideways offset up to max_rel_shear[a] L. rest: float64 (N, D),
    the undeformed grid (e.g. chainsim.systems.engine.meshgen.grid with per-axis spacing arrays).
    """
    dim, n, nx, ny, nz, grabbed, target, fixed_arr, has_fixed = _prepare(pos, shape, grabbed, target, fixed)
    if not isinstance(rest, np.ndarray) or rest.shape != pos.shape or rest.dtype != np.float64:
        raise ValueError(f"rest must be a float64 array of shape {pos.shape}")
    rest = np.ascontiguousarray(rest)
    lo, hi, sh = (
        _limits("min_rel", min_rel, dim),
        _limits("max_rel", max_rel, dim),
        _limits("max_rel_shear", max_rel_shear, dim),
    )
    if np.any(lo[:dim] < 0) or np.any(lo[:dim] > hi[:dim]) or np.any(sh[:dim] < 0):
        raise ValueError(
            f"need 0 <= min_rel <= max_rel and max_rel_shear >= 0, got {min_rel}, {max_rel}, {max_rel_shear}"
        )
    out = np.empty(n, dtype=np.int64)
    count = _grid_kernel(
        pos, rest, True, nx, ny, nz, grabbed, target, lo, hi, sh, fixed_arr, has_fixed, _DIR_AXIS, _DIR_SIGN, out
    )
    return (count, out[:count].copy()) if return_moved else count

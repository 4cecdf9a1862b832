"""SurfaceChainMail (thesis 4.4): a parametric (u, v) grid mapped onto a surface in 3-D.

A pull on a surface element is split in two (4.4, 4.4.3):
  * the tangential part moves the element in the (u, v) parameter grid, propagated with the
    relative-limit grid ChainMail of 4.3 (gibson.relative_grid_move);
  * the normal part is a scalar displacement along each element's surface normal, propagated by
    normal_cascade: a neighbour follows only when its normal offset differs from the mover's by more
    than max_rel_shear times their rest separation (4.4.2).
The two results are combined by mapping (u, v) back onto the surface and adding the normal offset
(surface_points). The mapping is any function uv -> (points, unit normals), e.g. cylinder().
"""

from __future__ import annotations

import numpy as np
from numba import njit

from chainsim.systems.engine.meshgen import grid

from .gibson import relative_grid_move
from .graph import Graph, build_graph


@njit(cache=True)
def _normal_kernel(disp, indptr, indices, link, alive, rest_len, grabbed, target, shear, fixed, has_fixed, stamp, out):
    for k in range(grabbed.shape[0]):
        g = grabbed[k]
        if stamp[g] == 1:
            return -2
        stamp[g] = 1
    count = 0
    for k in range(grabbed.shape[0]):
        g = grabbed[k]
        if has_fixed and fixed[g]:
            continue
        disp[g] = target[k]
        out[count] = g
        count += 1
    head = 0
    while head < count:
        s = out[head]
        head += 1
        for j in range(indptr[s], indptr[s + 1]):
            e = indices[j]
            lk = link[j]
            if stamp[e] == 1 or not alive[lk] or (has_fixed and fixed[e]):
                continue
            lim = shear[lk] * rest_len[lk]
            x = disp[e]
            if x - disp[s] > lim:
                disp[e] = disp[s] + lim
            elif x - disp[s] < -lim:
                disp[e] = disp[s] - lim
            if disp[e] != x:
                stamp[e] = 1
                out[count] = e
                count += 1
    return count


def normal_cascade(disp, graph: Graph, rest_len, grabbed, target, max_rel_shear, fixed=None) -> np.ndarray:
    """Propagate normal offsets (4.4.2) breadth first; disp (N,) float64 changes in place.

    rest_len: (M,) rest separation of each link; max_rel_shear: scalar or (M,). grabbed: (K,) distinct ids
    set to `target` (K,). A neighbour whose offset differs from its mover's by more than
    max_rel_shear * rest_len is clamped to that band and passes the move on; each element moves at most
    once. Returns the moved ids in order, grabbed first.
    """
    disp = disp if isinstance(disp, np.ndarray) else np.asarray(disp)
    if disp.dtype != np.float64 or disp.ndim != 1 or not disp.flags.c_contiguous:
        raise ValueError("disp must be a contiguous float64 array of shape (N,)")
    n, m = disp.shape[0], graph.links.shape[0]
    if graph.indptr.shape[0] != n + 1:
        raise ValueError(f"graph has {graph.indptr.shape[0] - 1} elements but disp has {n}")
    rest_len = np.ascontiguousarray(rest_len, dtype=np.float64)
    if rest_len.shape != (m,) or not np.all(np.isfinite(rest_len)) or np.any(rest_len < 0):
        raise ValueError(f"rest_len must be ({m},) finite non-negative link lengths")
    shear = np.asarray(max_rel_shear, dtype=np.float64)
    shear = np.full(m, float(shear)) if shear.ndim == 0 else np.ascontiguousarray(shear)
    if shear.shape != (m,) or not np.all(np.isfinite(shear)) or np.any(shear < 0):
        raise ValueError(f"max_rel_shear must be a finite value >= 0, scalar or ({m},)")
    grabbed = np.ascontiguousarray(np.atleast_1d(grabbed), dtype=np.int64)
    target = np.ascontiguousarray(np.atleast_1d(target), dtype=np.float64)
    if grabbed.ndim != 1 or len(grabbed) == 0 or target.shape != grabbed.shape:
        raise ValueError("grabbed and target must be non-empty 1-D arrays of the same length")
    if grabbed.min() < 0 or grabbed.max() >= n:
        raise ValueError(f"grabbed ids must lie in [0, {n})")
    if not np.all(np.isfinite(target)):
        raise ValueError("target must be finite")
    fixed_arr = np.zeros(1, dtype=np.bool_) if fixed is None else np.asarray(fixed, dtype=np.bool_)
    if fixed is not None and fixed_arr.shape != (n,):
        raise ValueError(f"fixed must be a bool array of shape ({n},) or None")
    stamp = np.zeros(n, dtype=np.int8)
    out = np.empty(n, dtype=np.int64)
    count = _normal_kernel(
        disp,
        graph.indptr,
        graph.indices,
        graph.link,
        graph.alive,
        rest_len,
        grabbed,
        target,
        shear,
        fixed_arr,
        fixed is not None,
        stamp,
        out,
    )
    if count < 0:
        raise ValueError("grabbed ids must be distinct")
    return out[:count].copy()


def cylinder(radius: float = 1.0):
    """Mapping of (u, v) = (arc length around, height) onto a cylinder about z: uv -> (points, normals)."""
    radius = float(radius)
    if not radius > 0:
        raise ValueError(f"radius must be > 0, got {radius}")

    def mapping(uv):
        uv = np.asarray(uv, dtype=np.float64)
        ang = uv[:, 0] / radius
        normals = np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)
        return normals * radius + np.stack([np.zeros_like(ang)] * 2 + [uv[:, 1]], axis=1), normals

    return mapping


def surface_points(mapping, uv, disp) -> np.ndarray:
    """Combine the two deformations (4.4.3): surface point at uv plus disp along the surface normal."""
    pts, normals = mapping(uv)
    return pts + np.asarray(disp, dtype=np.float64)[:, None] * normals


def surface_move(
    uv_pos,
    uv_rest,
    disp,
    shape,
    grabbed,
    target_uv,
    target_disp,
    min_rel,
    max_rel,
    max_rel_shear,
    fixed=None,
    graph: Graph | None = None,
):
    """One SurfaceChainMail move: tangential part on the (u, v) grid, normal part along normals (4.4).

    uv_pos, uv_rest: (N, 2) float64 grid parameters (element (i, j) has id i + nx*j, shape = (nx, ny));
    disp: (N,) normal offsets. Both change in place. graph: the grid's link graph (built from the grid
    when None). Returns (moved in the tangent plane, moved along the normal) as id arrays.
    """

    _, moved_uv = relative_grid_move(
        uv_pos, uv_rest, shape, grabbed, target_uv, min_rel, max_rel, max_rel_shear, fixed=fixed, return_moved=True
    )
    if graph is None:
        graph = build_graph(len(uv_rest), grid(tuple(shape))[1])
    rest_len = np.linalg.norm(uv_rest[graph.links[:, 1]] - uv_rest[graph.links[:, 0]], axis=1)
    moved_n = normal_cascade(
        disp, graph, rest_len, np.array([int(grabbed)]), np.array([float(target_disp)]), max_rel_shear, fixed=fixed
    )
    return moved_uv, moved_n

"""Topology changes with no precomputation: cutting links and adding links (thesis 4.5.2, 5.4).

Cutting follows 4.5.2: find the links near the blade with a bounding-box test on their end points,
then kill (Graph.cut: the link's flag and its two CSR entries' copies) every live link the blade
crosses. Nothing is rebuilt; the cascade and relaxation kernels skip dead links. Link ids never change,
so per-link material arrays stay valid.

Crossing rule. An end point lying exactly on the blade's line (2-D) or plane (3-D) counts as being on
its positive side. A link is cut when its two ends are on different sides and the crossing point lies on
the blade (blade end points included). So a blade running exactly through elements separates them
cleanly: each link on the line is cut on exactly one side, no element is left dangling twice.

add_links (suturing, joining parts) rebuilds the CSR with the new links appended after the old ones.
"""

from __future__ import annotations

import numpy as np

from .graph import Graph, build_graph


def _candidates(pos, graph, lo, hi):
    """Live link ids whose end-point bounding box overlaps [lo, hi] (vectorised O(M) prefilter)."""
    a = pos[graph.links[:, 0]]
    b = pos[graph.links[:, 1]]
    lmin = np.minimum(a, b)
    lmax = np.maximum(a, b)
    mask = graph.alive & np.all(lmax >= lo, axis=1) & np.all(lmin <= hi, axis=1)
    return np.flatnonzero(mask)


def _point(name, p, dim):
    p = np.asarray(p, dtype=np.float64).reshape(-1)
    if p.shape != (dim,) or not np.all(np.isfinite(p)):
        raise ValueError(f"{name} must be {dim} finite coordinates, got {p}")
    return p


def _check_pos(pos, graph, dim):
    if not isinstance(pos, np.ndarray) or pos.ndim != 2 or pos.shape[1] != dim:
        raise ValueError(f"pos must be an array of shape (N, {dim}), got {getattr(pos, 'shape', None)}")
    if pos.shape[0] != graph.indptr.shape[0] - 1:
        raise ValueError(f"graph has {graph.indptr.shape[0] - 1} elements but pos has {pos.shape[0]}")


def _cross2(o, u, p):
    """z of (u) x (p - o) for points p (K, 2): which side of the line through o along u."""
    return u[0] * (p[:, 1] - o[1]) - u[1] * (p[:, 0] - o[0])


def cut_segment(pos, graph: Graph, p0, p1, normal=None, depth=None) -> np.ndarray:
    """Kill every live link the blade p0-p1 crosses; returns the killed link ids (int64).

    pos (N, 2): the blade is the segment p0-p1 itself (normal and depth are ignored).
    pos (N, 3): the blade is the strip cut_plane_strip(p0, p1, normal, depth) sweeps; normal
    defaults to +z (or +y when the segment runs along z). The links are cut in the graph (Graph.cut).
    """
    dim = pos.shape[1] if isinstance(pos, np.ndarray) and pos.ndim == 2 else None
    if dim == 3:
        if normal is None:
            seg = _point("p1", p1, 3) - _point("p0", p0, 3)
            normal = (0.0, 0.0, 1.0)
            if np.linalg.norm(seg[:2]) <= 1e-9 * np.linalg.norm(seg):
                normal = (0.0, 1.0, 0.0)
        return cut_plane_strip(pos, graph, p0, p1, normal, depth=depth)
    _check_pos(pos, graph, 2)
    p0 = _point("p0", p0, 2)
    p1 = _point("p1", p1, 2)
    cand = _candidates(pos, graph, np.minimum(p0, p1), np.maximum(p0, p1))
    u = p1 - p0
    if cand.size == 0 or not np.any(u):
        return np.zeros(0, dtype=np.int64)
    a = np.asarray(pos[graph.links[cand, 0]], dtype=np.float64)
    b = np.asarray(pos[graph.links[cand, 1]], dtype=np.float64)
    sa = _cross2(p0, u, a) >= 0.0
    sb = _cross2(p0, u, b) >= 0.0
    # the blade's end points must lie on different sides of (or on) each link's line
    ab = b - a
    c0 = ab[:, 0] * (p0[1] - a[:, 1]) - ab[:, 1] * (p0[0] - a[:, 0])
    c1 = ab[:, 0] * (p1[1] - a[:, 1]) - ab[:, 1] * (p1[0] - a[:, 0])
    hit = (sa != sb) & (c0 * c1 <= 0.0)
    killed = cand[hit]
    graph.cut(killed)
    return killed


def cut_path(pos, graph: Graph, points, normal=None, depth=None) -> np.ndarray:
    """Cut along a polyline (K >= 2 points) segment by segment; returns all killed link ids.

    In 3-D each segment sweeps the strip of cut_segment / cut_plane_strip with the same normal/depth.
    """
    dim = pos.shape[1] if isinstance(pos, np.ndarray) and pos.ndim == 2 else 2
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != dim or len(points) < 2:
        raise ValueError(f"points must be a polyline of shape (K >= 2, {dim}), got {points.shape}")
    killed = [
        cut_segment(pos, graph, points[i], points[i + 1], normal=normal, depth=depth) for i in range(len(points) - 1)
    ]
    return np.concatenate(killed) if killed else np.zeros(0, dtype=np.int64)


def cut_plane_strip(pos, graph: Graph, p0, p1, normal, depth=None, two_sided: bool = True) -> np.ndarray:
    """3-D: kill every live link crossing the blade swept from segment p0-p1 along `normal`.

    The blade is {p0 + s (p1 - p0) + t n : 0 <= s <= 1, t_lo <= t <= depth}, n the unit normal, with
    t_lo = -depth when two_sided (a scalpel pressed through a surface reaches both sides) else 0.
    depth=None makes the strip unbounded along n: every link crossing the plane through p0-p1 spanned
    by n, at a point that projects between p0 and p1. The normal's length is ignored; it must not be
    parallel to p1 - p0. pos: (N, 3). The links are cut in the graph (Graph.cut); returns killed link ids.
    Surfaces in 3-D and tetrahedral volumes are cut the same way.
    """
    _check_pos(pos, graph, 3)
    p0 = _point("p0", p0, 3)
    p1 = _point("p1", p1, 3)
    n = _point("normal", normal, 3)
    u = p1 - p0
    uu = float(u @ u)
    if uu == 0.0:
        return np.zeros(0, dtype=np.int64)
    # the part of the normal perpendicular to the blade edge spans the blade with it
    n = n - (n @ u) / uu * u
    nn = float(np.linalg.norm(n))
    if nn <= 1e-12 * max(float(np.linalg.norm(_point("normal", normal, 3))), 1e-300):
        raise ValueError("cut_plane_strip: normal must not be parallel to p1 - p0")
    n = n / nn
    if depth is not None:
        depth = float(depth)
        if not (depth > 0.0) or not np.isfinite(depth):
            raise ValueError(f"depth must be a positive finite length or None, got {depth}")
    t_hi = np.inf if depth is None else depth
    t_lo = -t_hi if two_sided else 0.0
    plane_n = np.cross(u, n)
    # bounding box of the blade (unbounded along n when depth is None)
    lo = np.minimum(p0, p1)
    hi = np.maximum(p0, p1)
    for t in (t_lo, t_hi):
        if np.isfinite(t):
            lo = np.minimum(lo, np.minimum(p0, p1) + t * n)
            hi = np.maximum(hi, np.maximum(p0, p1) + t * n)
        else:
            lo = np.where(n != 0, -np.inf, lo)
            hi = np.where(n != 0, np.inf, hi)
    cand = _candidates(pos, graph, lo, hi)
    if cand.size == 0:
        return np.zeros(0, dtype=np.int64)
    a = np.asarray(pos[graph.links[cand, 0]], dtype=np.float64)
    b = np.asarray(pos[graph.links[cand, 1]], dtype=np.float64)
    ha = (a - p0) @ plane_n
    hb = (b - p0) @ plane_n
    cross = (ha >= 0.0) != (hb >= 0.0)
    t = ha / np.where(cross, ha - hb, 1.0)
    x = a + t[:, None] * (b - a) - p0
    s_coord = (x @ u) / uu  # u and n are orthogonal, so coordinates are plain projections
    t_coord = x @ n
    eps = 1e-12
    inside = (
        (s_coord >= -eps)
        & (s_coord <= 1.0 + eps)
        & (t_coord >= t_lo - eps * abs(t_lo if np.isfinite(t_lo) else 0.0))
        & (t_coord <= t_hi + eps * abs(t_hi if np.isfinite(t_hi) else 0.0))
    )
    killed = cand[cross & inside]
    graph.cut(killed)
    return killed


def add_links(graph: Graph, new_links) -> Graph:
    """New Graph with `new_links` (K, 2) appended as live links with ids M..M+K-1 (suturing, 5.4).

    Existing links keep their ids and alive flags, so per-link material arrays only need K new entries.
    Cost is O(N + M), a full CSR rebuild.
    """
    n = graph.indptr.shape[0] - 1
    new_links = np.asarray(new_links)
    if new_links.size == 0:
        new_links = np.zeros((0, 2), dtype=np.int64)
    if new_links.ndim != 2 or new_links.shape[1] != 2 or not np.issubdtype(new_links.dtype, np.integer):
        raise ValueError(
            f"new_links must be integer element-id pairs of shape (K, 2), got {new_links.dtype} {new_links.shape}"
        )
    links = np.concatenate([graph.links, new_links.astype(np.int64)])
    alive = np.concatenate([graph.alive, np.ones(len(links) - len(graph.links), dtype=np.bool_)])
    return build_graph(n, links, alive=alive)

"""Rays and triangle meshes without GL: ray-triangle hits, nearest surface point, triangles of live links.

A vectorised two-sided Moller-Trumbore over every triangle (in chunks, to bound memory); the picking
system (chainsim.systems.view.picking) runs it on the meshes the renderer draws.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

EPS = 1e-12


# -- geometry ------------------------------------------------------------------------------------


def ray_triangles(
    origin: ArrayLike, direction: ArrayLike, v0: np.ndarray, v1: np.ndarray, v2: np.ndarray
) -> np.ndarray:
    """Distance along the ray to each triangle (inf where missed); triangles given as (F, 3) corners."""
    o = np.asarray(origin, float)
    d = np.asarray(direction, float)
    e1 = v1 - v0
    e2 = v2 - v0
    p = np.cross(d, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > EPS
    inv = np.zeros_like(det)
    inv[ok] = 1.0 / det[ok]
    s = o - v0
    u = np.einsum("ij,ij->i", s, p) * inv
    q = np.cross(s, e1)
    v = (q @ d) * inv
    t = np.einsum("ij,ij->i", e2, q) * inv
    hit = ok & (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0) & (t > 0.0)
    return np.where(hit, t, np.inf)


def ray_mesh(
    origin: ArrayLike, direction: ArrayLike, vertices: np.ndarray, triangles: np.ndarray, chunk: int = 200_000
) -> tuple[int, float] | None:
    """(triangle, distance) of the nearest hit, or None."""
    if len(triangles) == 0:
        return None
    best_t, best_i = np.inf, -1
    for s in range(0, len(triangles), chunk):
        tri = triangles[s : s + chunk]
        t = ray_triangles(origin, direction, vertices[tri[:, 0]], vertices[tri[:, 1]], vertices[tri[:, 2]])
        i = int(np.argmin(t))
        if t[i] < best_t:
            best_t, best_i = float(t[i]), s + i
    return None if best_i < 0 else (best_i, best_t)


def closest_on_mesh(vertices: np.ndarray, triangles: np.ndarray, point: ArrayLike) -> tuple[int, np.ndarray]:
    """(triangle, point) on the mesh surface nearest to `point`."""
    # trimesh takes most of a second to import: not at start (the window loads it behind its first picture)
    from trimesh.triangles import closest_point  # noqa: PLC0415

    p = np.asarray(point, float)
    corners = vertices[triangles]
    cp = closest_point(corners, np.broadcast_to(p, (len(triangles), 3)))
    d2 = np.einsum("ij,ij->i", cp - p, cp - p)
    i = int(np.argmin(d2))
    return i, cp[i].copy()


def triangle_links(triangles: np.ndarray, links: np.ndarray) -> np.ndarray:
    """(F, 3) link id of each triangle edge (v0v1, v1v2, v2v0), -1 where the edge is not a link."""
    if len(links) == 0 or len(triangles) == 0:
        return np.full((len(triangles), 3), -1, np.int64)
    n = int(max(triangles.max(), links.max())) + 1
    lk = np.minimum(links[:, 0], links[:, 1]).astype(np.int64) * n + np.maximum(links[:, 0], links[:, 1])
    order = np.argsort(lk)
    lk_sorted = lk[order]
    out = np.empty((len(triangles), 3), np.int64)
    for j, (a, b) in enumerate(((0, 1), (1, 2), (2, 0))):
        ea, eb = triangles[:, a].astype(np.int64), triangles[:, b].astype(np.int64)
        key = np.minimum(ea, eb) * n + np.maximum(ea, eb)
        pos = np.clip(np.searchsorted(lk_sorted, key), 0, len(lk_sorted) - 1)
        found = lk_sorted[pos] == key
        out[:, j] = np.where(found, order[pos], -1)
    return out


# -- the world -----------------------------------------------------------------------------------

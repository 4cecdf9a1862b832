"""Test meshes for ChainMail benchmarks and the chainmail-demo pack (thesis 5.3 examples).

    curved_patch(n)      an irregular triangulated patch of a sphere (a stand-in for the skull-skin patch
                         of Fig. 5.6: 345 elements, mostly triangles)
    brain_surface(n)     a closed surface with gyri-like folds (Fig. 5.7: 1043 elements)
    surface_sheet(n)     a triangulated square sheet of about n elements in 3-D (scaling runs)
    tet_cube(n)          a structured tet block of about n elements (scaling runs, Fig. 5.9 at n = 343)

`python -m chainsim.tools.bench.meshes OUTDIR` writes the demo pack's mesh files.
"""

from __future__ import annotations

import sys
from pathlib import Path

import meshio
import numpy as np
import trimesh
from scipy.spatial import ConvexHull, Delaunay

from chainsim.systems.engine import meshgen


def curved_patch(n: int = 345, radius: float = 80.0, width: float = 60.0, seed: int = 7):
    """(vertices (n, 3), triangles) of a jittered-disc Delaunay patch lifted onto a sphere cap."""

    rng = np.random.default_rng(seed)
    # golden-angle disc gives an even but irregular spacing; a little jitter breaks the symmetry
    k = np.arange(n)
    r = np.sqrt((k + 0.5) / n) * width / 2
    th = k * np.pi * (3 - np.sqrt(5))
    xy = np.stack([r * np.cos(th), r * np.sin(th)], 1)
    spacing = width / np.sqrt(n)
    xy[: int(n * 0.85)] += rng.normal(0.0, 0.12 * spacing, size=(int(n * 0.85), 2))
    tri = Delaunay(xy).simplices.astype(np.int64)
    # drop slivers on the convex hull (long thin triangles the disc rim produces)
    e = np.linalg.norm(xy[tri] - xy[np.roll(tri, 1, axis=1)], axis=2)
    tri = tri[e.max(axis=1) < 2.2 * spacing]
    used = np.unique(tri)
    remap = np.full(n, -1)
    remap[used] = np.arange(len(used))
    xy, tri = xy[used], remap[tri]
    z = np.sqrt(radius**2 - np.sum(xy**2, axis=1)) - radius
    verts = np.column_stack([xy, z])
    return verts, _orient_up(verts, tri)


def _orient_up(verts, tri):
    nrm = np.cross(verts[tri[:, 1]] - verts[tri[:, 0]], verts[tri[:, 2]] - verts[tri[:, 0]])
    flip = nrm[:, 2] < 0
    tri = tri.copy()
    tri[flip] = tri[flip][:, [0, 2, 1]]
    return tri


def brain_surface(n: int = 1043, radius: float = 40.0, folds: float = 0.07):
    """(vertices, triangles) of a closed fibonacci-sphere surface with folded (gyri-like) relief."""

    k = np.arange(n) + 0.5
    phi = np.arccos(1 - 2 * k / n)
    th = np.pi * (1 + 5**0.5) * k
    unit = np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], 1)
    hull = ConvexHull(unit)
    tri = hull.simplices.astype(np.int64)
    c = unit[tri].mean(axis=1)
    nrm = np.cross(unit[tri[:, 1]] - unit[tri[:, 0]], unit[tri[:, 2]] - unit[tri[:, 0]])
    flip = np.sum(nrm * c, axis=1) < 0
    tri[flip] = tri[flip][:, [0, 2, 1]]
    x, y, z = unit.T
    relief = (np.sin(7 * x + 2 * y) * np.cos(6 * z - y) + 0.6 * np.sin(9 * y + 3 * z) * np.cos(8 * x)) / 1.6
    scale = np.array([1.15, 0.9, 0.8])  # elongated like a hemisphere pair, flatter below
    verts = unit * radius * (1 + folds * relief)[:, None] * scale
    return verts, tri


def surface_sheet(n: int, spacing: float = 1.0):
    """(vertices, triangles, links) of a triangulated square sheet of about n elements in 3-D.

    Equal to meshgen.triangulated_grid(side, side, spacing, dim=3), with the fast link builder.
    """
    side = max(2, int(round(np.sqrt(n))))
    idx = meshgen.grid_index((side, side))
    ii, jj = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    pos = np.zeros((side * side, 3))
    pos[idx.ravel(), 0] = ii.ravel() * spacing
    pos[idx.ravel(), 1] = jj.ravel() * spacing
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    return pos, tris, fast_links(len(pos), tris)


def relabel(pos: np.ndarray, links: np.ndarray, perm: np.ndarray):
    """Positions and links renumbered by `perm` (new-to-old); links re-sorted as a loader would."""
    n = len(pos)
    inv = np.empty_like(perm)
    inv[perm] = np.arange(n, dtype=perm.dtype)
    a, b = inv[links[:, 0]], inv[links[:, 1]]
    keys = np.sort(np.minimum(a, b) * n + np.maximum(a, b))
    return np.ascontiguousarray(pos[perm]), np.stack([keys // n, keys % n], axis=1), inv


def tet_cube(n: int, spacing: float = 1.0):
    """(vertices, tets, links) of a cube of about n elements (6 tets per cell, up to 14 links).

    Equal to meshgen.tet_grid(side, side, side) but built with 1-D link keys, so a million elements
    take seconds rather than minutes.
    """
    side = max(2, int(round(n ** (1 / 3))))
    return fast_tet_grid(side, side, side, spacing)


def fast_tet_grid(nx: int, ny: int, nz: int, spacing: float = 1.0):
    idx = meshgen.grid_index((nx, ny, nz))
    ii, jj, kk = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    pos = np.zeros((nx * ny * nz, 3))
    flat = idx.ravel()
    pos[flat, 0] = ii.ravel() * spacing
    pos[flat, 1] = jj.ravel() * spacing
    pos[flat, 2] = kk.ravel() * spacing
    c = [idx[i : nx - 1 + i, j : ny - 1 + j, k : nz - 1 + k].ravel() for k in (0, 1) for j in (0, 1) for i in (0, 1)]
    paths = [(1, 3), (1, 5), (2, 3), (2, 6), (4, 5), (4, 6)]
    tets = np.concatenate([np.stack([c[0], c[p], c[q], c[7]], 1) for p, q in paths]).astype(np.int64)
    return pos, tets, fast_links(len(pos), tets)


def fast_links(n: int, cells: np.ndarray) -> np.ndarray:
    """meshgen.links_from_cells through 1-D int64 keys (same result, sorted lexicographically)."""
    k = cells.shape[1]
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)] if k == 4 else [(i, (i + 1) % k) for i in range(k)]
    keys = []
    for a, b in pairs:
        lo = np.minimum(cells[:, a], cells[:, b])
        hi = np.maximum(cells[:, a], cells[:, b])
        keys.append(lo * n + hi)
    keys = np.sort(np.concatenate(keys))
    if len(keys):
        keys = keys[np.concatenate([[True], keys[1:] != keys[:-1]])]  # np.unique is far slower here
    return np.stack([keys // n, keys % n], axis=1)


def write_demo_meshes(out: Path) -> None:

    out.mkdir(parents=True, exist_ok=True)
    v, t = curved_patch()
    trimesh.Trimesh(v, t, process=False).export(out / "skull_patch.ply")
    v, t = brain_surface()
    trimesh.Trimesh(v, t, process=False).export(out / "brain.ply")
    pos, tets, _ = meshgen.tet_grid(7, 7, 7, spacing=5.0)
    pos = pos - pos.mean(axis=0)
    meshio.write(out / "volume.vtu", meshio.Mesh(pos, [("tetra", tets)]), binary=False)


if __name__ == "__main__":  # pragma: no cover
    write_demo_meshes(Path(sys.argv[1] if len(sys.argv) > 1 else "assets/chainmail-demo/meshes"))

"""Locality reordering of meshes: renumber vertices so linked elements sit close in memory.

A ChainMail cascade (thesis 5.2.3) walks the link graph; when neighbours have nearby ids, the positions
it reads and writes share cache lines and the walk runs at memory speed instead of waiting on misses.
Meshes from scanners and mesh generators often come with scattered ids. Two orders are offered:

    rcm     reverse Cuthill-McKee over the link graph (scipy): a small bandwidth, follows the topology
    morton  a Z-order (Morton) space-filling curve over the vertex positions: follows the geometry

`reorder_mesh` (used by packs with `reorder = true`) returns a renumbered copy: vertices permuted,
triangles / tetrahedra / links mapped to the new ids and the cells sorted by their first vertex.
"""

from __future__ import annotations

from typing import overload

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import reverse_cuthill_mckee

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.meshes import MeshData

METHODS = ("rcm", "morton")


def rcm_permutation(n: int, links: np.ndarray) -> np.ndarray:
    """New-to-old order (perm[new] = old) from reverse Cuthill-McKee on the undirected links."""

    links = np.asarray(links, dtype=np.int64).reshape(-1, 2)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    rows = np.concatenate([links[:, 0], links[:, 1]])
    cols = np.concatenate([links[:, 1], links[:, 0]])
    mat = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n, n)).tocsr()
    return np.asarray(reverse_cuthill_mckee(mat, symmetric_mode=True), dtype=np.int64)


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """Insert two zero bits between each of the low 21 bits (3-D Morton interleave)."""
    v = v.astype(np.uint64) & np.uint64(0x1FFFFF)
    v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
    v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
    v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
    v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
    v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
    return v


def morton_permutation(points: np.ndarray) -> np.ndarray:
    """New-to-old order along a Z-order curve through the points' bounding box (1-3 coordinates)."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or len(pts) == 0:
        return np.zeros(0, dtype=np.int64)
    lo = pts.min(axis=0)
    span = np.maximum(pts.max(axis=0) - lo, 1e-300)
    q = np.floor((pts - lo) / span * ((1 << 21) - 1)).astype(np.int64)
    code = np.zeros(len(pts), dtype=np.uint64)
    for a in range(min(pts.shape[1], 3)):
        code |= _spread_bits(q[:, a]) << np.uint64(a)
    return np.argsort(code, kind="stable").astype(np.int64)


def inverse(perm: np.ndarray) -> np.ndarray:
    """Old-to-new map of a new-to-old permutation."""
    inv = np.empty_like(perm)
    inv[perm] = np.arange(len(perm), dtype=perm.dtype)
    return inv


@overload
def _cells(cells: np.ndarray, inv: np.ndarray) -> np.ndarray: ...
@overload
def _cells(cells: None, inv: np.ndarray) -> None: ...
def _cells(cells: np.ndarray | None, inv: np.ndarray) -> np.ndarray | None:
    if cells is None:
        return None
    out = inv[np.asarray(cells, dtype=np.int64)]
    if len(out) == 0:
        return out
    # keep each cell's vertex order (orientation), sort the cells by where they start in memory
    return out[np.argsort(out.min(axis=1), kind="stable")]


def permute_links(links: np.ndarray, inv: np.ndarray) -> np.ndarray:

    return meshgen.unique_links(inv[np.asarray(links, dtype=np.int64)])


def permute_mesh(mesh: MeshData, perm: np.ndarray) -> MeshData:
    """MeshData renumbered by `perm` (new-to-old)."""

    perm = np.asarray(perm, dtype=np.int64)
    n = len(mesh.vertices)
    if perm.shape != (n,) or not np.array_equal(np.sort(perm), np.arange(n)):
        raise ValueError(f"perm must be a permutation of 0..{n - 1}")
    inv = inverse(perm)
    return MeshData(
        vertices=np.ascontiguousarray(mesh.vertices[perm]),
        triangles=_cells(mesh.triangles, inv),
        tets=_cells(mesh.tets, inv),
        links=None if mesh.links is None else permute_links(mesh.links, inv),
    )


def reorder_mesh(mesh: MeshData, method: str = "rcm") -> MeshData:
    """A copy of `mesh` with vertices renumbered for locality (see module docstring)."""
    if method not in METHODS:
        raise ValueError(f"reorder method must be one of {', '.join(METHODS)}, got {method!r}")
    if method == "morton":
        perm = morton_permutation(mesh.vertices)
    else:
        perm = rcm_permutation(len(mesh.vertices), mesh.edge_links())
    return permute_mesh(mesh, perm)

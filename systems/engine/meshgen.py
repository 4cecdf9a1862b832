"""Structured test meshes as flat arrays: chains, grids, triangulated sheets, tetrahedral blocks.

Every generator returns plain numpy arrays (positions float64, links int64 with each undirected pair
once, lowest index first), so kernels, benchmarks, studies and packs share one definition of "an
11 x 11 grid" (thesis 6.2.1) or "a 7 x 7 x 7 volume" (thesis 5.3).
"""

from __future__ import annotations

import numpy as np


def unique_links(links: np.ndarray) -> np.ndarray:
    """Sort each pair, drop self-links and duplicates; returns (M, 2) int64 in lexicographic order."""
    links = np.asarray(links, dtype=np.int64).reshape(-1, 2)
    links = np.sort(links, axis=1)
    links = links[links[:, 0] != links[:, 1]]
    if len(links) == 0:
        return links.reshape(0, 2)
    # one int64 key per pair: sorting keys is far cheaper than np.unique(axis=0) on big meshes
    n = int(links.max()) + 1
    keys = np.sort(links[:, 0] * n + links[:, 1])
    keys = keys[np.concatenate(([True], keys[1:] != keys[:-1]))]
    return np.stack([keys // n, keys % n], axis=1)


def links_from_cells(cells: np.ndarray) -> np.ndarray:
    """Every edge of every cell (triangles, quads as cycles; tetrahedra as all 6 pairs)."""
    cells = np.asarray(cells, dtype=np.int64)
    k = cells.shape[1]
    if k == 4:
        pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    else:
        pairs = [(i, (i + 1) % k) for i in range(k)]
    return unique_links(np.concatenate([cells[:, [a, b]] for a, b in pairs]))


def links_from_polygons(polygons: np.ndarray) -> np.ndarray:
    """Edges of polygons given as cycles (triangles, quads, ...), each cycle closed."""
    polygons = np.asarray(polygons, dtype=np.int64)
    k = polygons.shape[1]
    return unique_links(np.concatenate([polygons[:, [i, (i + 1) % k]] for i in range(k)]))


def chain(n: int, spacing: float = 1.0, dim: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """n elements on a straight line along x, embedded in `dim`-D space."""
    pos = np.zeros((n, dim))
    pos[:, 0] = np.arange(n) * spacing
    links = np.stack([np.arange(n - 1), np.arange(1, n)], axis=1).astype(np.int64)
    return pos, links


def grid_index(shape: tuple[int, ...]) -> np.ndarray:
    """Array of element ids indexed [i, j(, k)], with id = i + nx*(j + ny*k) (x varies fastest)."""
    return np.arange(int(np.prod(shape)), dtype=np.int64).reshape(shape[::-1]).T


def grid(
    shape: tuple[int, ...], spacing: float | tuple[float, ...] = 1.0, dim: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Rectilinear grid with 4 (2-D) or 6 (3-D) neighbours, as in Gibson's ChainMail (thesis 4.2.1).

    `shape` is (nx, ny) or (nx, ny, nz); element (i, j[, k]) has id i + nx*(j + ny*k).
    `spacing` is a scalar or one array per axis of grid-line coordinates (non-uniform grids, 4.3).
    """
    shape = tuple(int(s) for s in shape)
    d = len(shape)
    dim = d if dim is None else dim
    axes = []
    for a, n in enumerate(shape):
        if isinstance(spacing, (int, float, np.integer, np.floating)):
            axes.append(np.arange(n) * float(spacing))
        else:
            coords = np.asarray(spacing[a], dtype=np.float64)
            if coords.shape != (n,):
                raise ValueError(f"spacing[{a}] must have {n} coordinates, got {coords.shape}")
            axes.append(coords)
    mesh = np.meshgrid(*axes, indexing="ij")
    idx = grid_index(shape)
    n = int(np.prod(shape))
    pos = np.zeros((n, dim))
    for a in range(d):
        pos[idx.ravel(), a] = mesh[a].ravel()
    links = []
    for a in range(d):
        lo = [slice(None)] * d
        hi = [slice(None)] * d
        lo[a] = slice(0, -1)
        hi[a] = slice(1, None)
        links.append(np.stack([idx[tuple(lo)].ravel(), idx[tuple(hi)].ravel()], axis=1))
    return pos, unique_links(np.concatenate(links))


def triangulated_grid(
    nx: int, ny: int, spacing: float = 1.0, dim: int = 2
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """nx x ny elements, each quad split into two triangles; returns (positions, triangles, links)."""
    pos, _ = grid((nx, ny), spacing, dim)
    idx = grid_index((nx, ny))
    a = idx[:-1, :-1].ravel()
    b = idx[1:, :-1].ravel()
    c = idx[1:, 1:].ravel()
    d = idx[:-1, 1:].ravel()
    tris = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.int64)
    return pos, tris, links_from_polygons(tris)


def tet_grid(nx: int, ny: int, nz: int, spacing: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Block of nx*ny*nz elements, each cube split into 6 tetrahedra sharing the main diagonal.

    Returns (positions (N,3), tets (T,4), links (M,2)). Interior elements have 14 links, like the
    thesis's 7 x 7 x 7 volume (5.3: 343 elements, up to 14 neighbours).
    """
    pos, _ = grid((nx, ny, nz), spacing, 3)
    idx = grid_index((nx, ny, nz))
    c = [idx[i : nx - 1 + i, j : ny - 1 + j, k : nz - 1 + k].ravel() for k in (0, 1) for j in (0, 1) for i in (0, 1)]
    # corner numbering: c[i + 2j + 4k]; the six tets around the diagonal c0 -> c7
    paths = [(1, 3), (1, 5), (2, 3), (2, 6), (4, 5), (4, 6)]
    tets = np.concatenate([np.stack([c[0], c[p], c[q], c[7]], 1) for p, q in paths]).astype(np.int64)
    return pos, tets, links_from_cells(tets)


def random_graph(
    n: int, m: int, dim: int, rng: np.random.Generator, scale: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Random positions and a connected random link graph (a random spanning tree plus extra links)."""
    pos = rng.uniform(0.0, scale, size=(n, dim))
    perm = rng.permutation(n)
    tree = np.stack([perm[1:], perm[rng.integers(0, np.arange(1, n))]], axis=1) if n > 1 else np.zeros((0, 2))
    extra = rng.integers(0, n, size=(max(m - (n - 1), 0), 2))
    return pos, unique_links(np.concatenate([tree.astype(np.int64), extra]))

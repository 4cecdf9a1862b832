"""Link graph of a ChainMail object: CSR adjacency over undirected links (thesis 5.2.1).

The thesis stores a list of neighbour identifiers per element; here the same information lives in flat
compressed-sparse-row arrays so numba kernels can walk it without Python objects. Each undirected link
appears twice in the CSR (once from each end) and carries its link id, so per-link data (materials,
the `alive` flag flipped by cutting, thesis 4.5.2) is shared by both directions.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


class Graph(NamedTuple):
    """CSR adjacency over undirected links.

    indptr:  int64 (N+1,)  neighbours of element i are indices[indptr[i]:indptr[i+1]]
    indices: int64 (2M,)   neighbour ids
    link:    int64 (2M,)   undirected link id of each CSR entry
    links:   int64 (M, 2)  endpoints of each link
    alive:   bool (M,)     False once a link is cut; CSR entries of dead links are skipped
    """

    indptr: np.ndarray
    indices: np.ndarray
    link: np.ndarray
    links: np.ndarray
    alive: np.ndarray

    @property
    def n_elements(self) -> int:
        return len(self.indptr) - 1

    @property
    def n_links(self) -> int:
        return len(self.links)


def _check_links(n: int, links) -> np.ndarray:
    if n < 0:
        raise ValueError(f"number of elements must be >= 0, got {n}")
    links = np.asarray(links)
    if links.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if links.ndim != 2 or links.shape[1] != 2:
        raise ValueError(f"links must have shape (M, 2), got {links.shape}")
    if not np.issubdtype(links.dtype, np.integer):
        raise ValueError(f"links must hold integer element ids, got dtype {links.dtype}")
    links = np.ascontiguousarray(links, dtype=np.int64)
    if links.min() < 0 or links.max() >= n:
        raise ValueError(f"link endpoints must be element ids in [0, {n}), got range [{links.min()}, {links.max()}]")
    if np.any(links[:, 0] == links[:, 1]):
        bad = int(np.flatnonzero(links[:, 0] == links[:, 1])[0])
        raise ValueError(f"link {bad} joins element {links[bad, 0]} to itself; self-links are not allowed")
    return links


def build_graph(n: int, links: np.ndarray, alive: np.ndarray | None = None) -> Graph:
    """CSR graph of `n` elements joined by undirected `links` (M, 2); link ids are row numbers.

    Within each element's row the neighbours are listed in increasing link id, so a cascade's visiting
    order follows from the link list alone. `alive` (optional, bool (M,))
    carries over cut links; by default every link is alive.
    """
    n = int(n)
    links = _check_links(n, links)
    m = len(links)
    src = np.concatenate([links[:, 0], links[:, 1]])
    dst = np.concatenate([links[:, 1], links[:, 0]])
    lid = np.concatenate([np.arange(m, dtype=np.int64), np.arange(m, dtype=np.int64)])
    perm = np.lexsort((lid, src))
    counts = np.bincount(src, minlength=n) if m else np.zeros(n, dtype=np.int64)
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    if alive is None:
        alive = np.ones(m, dtype=np.bool_)
    else:
        alive = np.ascontiguousarray(alive, dtype=np.bool_).copy()
        if alive.shape != (m,):
            raise ValueError(f"alive must have shape ({m},), got {alive.shape}")
    return Graph(indptr, np.ascontiguousarray(dst[perm]), np.ascontiguousarray(lid[perm]), links, alive)


def degree(graph: Graph) -> np.ndarray:
    """Number of live links at each element (dead links from cutting excluded)."""
    alive_entries = graph.alive[graph.link].astype(np.int64)
    src = np.repeat(np.arange(graph.n_elements), np.diff(graph.indptr))
    return np.bincount(src, weights=alive_entries, minlength=graph.n_elements).astype(np.int64)


def components(graph: Graph) -> np.ndarray:
    """Connected-component label of every element over live links (scipy sparse graph)."""

    n = graph.n_elements
    live = graph.links[graph.alive]
    mat = coo_matrix((np.ones(len(live)), (live[:, 0], live[:, 1])), shape=(n, n))
    return connected_components(mat, directed=False)[1]


def fixed_mask(fixed, n: int) -> tuple[np.ndarray, bool]:
    """(bool array of shape (n,), True) for an anchor mask, or a 1-element placeholder and False for None."""
    if fixed is None:
        return np.zeros(1, dtype=np.bool_), False
    arr = np.ascontiguousarray(fixed, dtype=np.bool_)
    if arr.shape != (n,):
        raise ValueError(f"fixed must be a bool array of shape ({n},) or None, got {arr.shape}")
    return arr, True

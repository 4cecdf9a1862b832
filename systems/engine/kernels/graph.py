"""Link graph of a ChainMail object: CSR adjacency over undirected links (thesis 5.2.1), and the owner
of the per-link data (alive flags, materials) in both link order and CSR entry order.

The thesis stores a list of neighbour identifiers per element; here the same information lives in flat
compressed-sparse-row arrays so numba kernels can walk it without Python objects. Each undirected link
appears twice in the CSR (once from each end) and carries its link id. Per-link data (materials, the
`alive` flag flipped by cutting, thesis 4.5.2) is kept by link id for callers and copied into CSR entry
order for the kernels, which then read it in the order they read `indices` instead of by a random link
id; the Graph is the only writer of both copies.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import ArrayLike
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


class Graph:
    """CSR adjacency over undirected links, and the one owner of the per-link data the kernels read.

    indptr:  int64 (N+1,)  neighbours of element i are indices[indptr[i]:indptr[i+1]]
    indices: int64 (2M,)   neighbour ids
    link:    int64 (2M,)   undirected link id of each CSR entry
    links:   int64 (M, 2)  endpoints of each link
    alive:   bool (M,)     False once a link is cut (read-only: cut through `cut` / `set_alive`)
    n_dead:  int           how many links are cut

    The kernels read the per-link data in CSR entry order, so that it streams with `indices` instead of
    being fetched by link id: `entry_alive` (2M,) mirrors `alive`, and the bound materials (per-link
    amin, amax, beta) are mirrored as `entry_amin`, `entry_amax`, `entry_beta` (2M,), or as one value
    each with `mat_stride` 0 when every link has the same material. Every write goes through this
    object (cut, set_alive, revive, bind_materials; add links with topology.add_links), and the arrays it
    hands out are read-only, so the two orders cannot drift apart.
    """

    __slots__ = (
        "indptr",
        "indices",
        "link",
        "links",
        "_alive",
        "alive",
        "_entry_alive",
        "entry_alive",
        "amin",
        "amax",
        "beta",
        "entry_amin",
        "entry_amax",
        "entry_beta",
        "mat_stride",
        "version",
        "n_dead",
    )

    def __init__(self, indptr, indices, link, links, alive=None):
        self.indptr = _frozen(indptr)
        self.indices = _frozen(indices)
        self.link = _frozen(link)
        self.links = _frozen(links)
        m = self.links.shape[0]
        self._alive = np.ones(m, dtype=np.bool_) if alive is None else np.array(alive, dtype=np.bool_, copy=True)
        if self._alive.shape != (m,):
            raise ValueError(f"alive must have shape ({m},), got {self._alive.shape}")
        self.alive = _frozen(self._alive.view())
        self._entry_alive = np.ascontiguousarray(self._alive[self.link])
        # how many links are cut: with none, the breadth-first cascade skips reading the alive flags
        self.n_dead = int(m - np.count_nonzero(self._alive))
        self.entry_alive = _frozen(self._entry_alive.view())
        self.amin = self.amax = self.beta = None
        self.entry_amin = self.entry_amax = self.entry_beta = None
        self.mat_stride = 0
        # bumped by every change of an alive flag, so caches of the link structure (the rigid cascade's
        # breadth-first tree) can tell they are stale without comparing the flags
        self.version = 0

    @property
    def n_elements(self) -> int:
        return len(self.indptr) - 1

    @property
    def n_links(self) -> int:
        return len(self.links)

    # -- alive flags ---------------------------------------------------------------------------------

    def set_alive(self, ids, value: bool = True) -> np.ndarray:
        """Set the alive flag of links `ids` (int ids or a bool mask over links); returns the ids whose
        flag changed."""
        ids = np.asarray(ids)
        if ids.dtype == np.bool_:
            if ids.shape != self._alive.shape:
                raise ValueError(f"a link mask must have shape {self._alive.shape}, got {ids.shape}")
            ids = np.flatnonzero(ids)
        ids = np.atleast_1d(ids).astype(np.int64, copy=False)
        if ids.size and (ids.min() < 0 or ids.max() >= self._alive.shape[0]):
            raise ValueError(f"link ids must be in [0, {self._alive.shape[0]})")
        changed = np.unique(ids[self._alive[ids] != bool(value)])
        if changed.size:
            self._alive[changed] = bool(value)
            self.n_dead += -len(changed) if value else len(changed)
            _set_entries(self._entry_alive, self.indptr, self.link, self.links, changed, bool(value))
            self.version += 1
        return changed

    def cut(self, ids) -> np.ndarray:
        """Mark links `ids` dead (thesis 4.5.2); returns the ids that were alive."""
        return self.set_alive(ids, False)

    def revive(self) -> None:
        """Every link alive again (a reset to the rest shape)."""
        self._alive[:] = True
        self._entry_alive[:] = True
        self.n_dead = 0
        self.version += 1

    # -- materials -----------------------------------------------------------------------------------

    def bind_materials(self, amin, amax, beta) -> None:
        """Make (amin, amax, beta), per-link float arrays of length M (see material_arrays), the materials
        the kernels read. The arrays are frozen (read-only) so they cannot change behind the CSR-order
        copy; bind new arrays to change a material. Binding the arrays already bound costs nothing."""
        if amin is self.amin and amax is self.amax and beta is self.beta:
            return
        m = self.links.shape[0]
        for name, arr in (("amin", amin), ("amax", amax), ("beta", beta)):
            if type(arr) is not np.ndarray or arr.shape != (m,) or arr.dtype.char not in "fd":
                raise ValueError(f"{name} must be a per-link float array of shape ({m},) (see material_arrays)")
        for arr in (amin, amax, beta):
            arr.flags.writeable = False
        uniform = m == 0 or all(bool(np.all(arr == arr[0])) for arr in (amin, amax, beta))
        if uniform:
            first = lambda arr: np.full(1, arr[0] if m else 1.0, dtype=np.float64)
            ea, eb, ec = first(amin), first(amax), first(beta)
        else:
            ea, eb, ec = (np.ascontiguousarray(arr[self.link], dtype=np.float64) for arr in (amin, amax, beta))
        for arr in (ea, eb, ec):
            arr.flags.writeable = False
        self.entry_amin, self.entry_amax, self.entry_beta = ea, eb, ec
        self.mat_stride = 0 if uniform else 1
        self.amin, self.amax, self.beta = amin, amax, beta

    @property
    def kernel_args(self) -> tuple:
        """(indptr, indices, entry_alive, entry_amin, entry_amax, entry_beta, mat_stride) for the kernels."""
        if self.entry_amin is None:
            raise ValueError("no materials bound to this graph (bind_materials, or pass them to cascade)")
        return (
            self.indptr,
            self.indices,
            self.entry_alive,
            self.entry_amin,
            self.entry_amax,
            self.entry_beta,
            self.mat_stride,
        )


def _frozen(arr):
    arr = np.asarray(arr)
    arr.flags.writeable = False
    return arr


@njit(cache=True)
def _set_entries(entry_alive, indptr, link, links, ids, value) -> None:
    """The two CSR entries of each link in ids take `value` (a scan of each end's row; rows are short)."""
    for k in range(ids.shape[0]):
        lid = ids[k]
        for end in range(2):
            a = links[lid, end]
            for j in range(indptr[a], indptr[a + 1]):
                if link[j] == lid:
                    entry_alive[j] = value
                    break


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
    links = np.array(links, dtype=np.int64, copy=True, order="C")  # the graph's own (it freezes it)
    if links.min() < 0 or links.max() >= n:
        raise ValueError(f"link endpoints must be element ids in [0, {n}), got range [{links.min()}, {links.max()}]")
    if np.any(links[:, 0] == links[:, 1]):
        bad = int(np.flatnonzero(links[:, 0] == links[:, 1])[0])
        raise ValueError(f"link {bad} joins element {links[bad, 0]} to itself; self-links are not allowed")
    return links


def build_graph(n: int, links: ArrayLike, alive: np.ndarray | None = None) -> Graph:
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

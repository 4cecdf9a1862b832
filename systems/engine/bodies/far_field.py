"""The far field of a sleeping hybrid body: where the nodes it does not solve go under a pull.

Sleeping borrows the locality of the ChainMail cascade (thesis 5.2.3): a sleeping body solves the region
around the tool only. It used to hold the rest where it was. Under a pull the whole body moves, though:
each far node by less than the sleep threshold, but a hundred thousand of them carry a large share of
the displacement field (on a 111k-node slab, held sleepers left the shape 27 % from the whole body's,
relative to the field).

Far from the tool the strains are small and the shape depends on the force the tool applies, not on how
that force is spread over the grabbed nodes (Saint-Venant). So the sleepers are placed on the linear
response of the whole body to the tool's force, on a coarse grid: u = P (P^T K P)^-1 P^T T, with K the
rest stiffness of the loose nodes (every node but the fixed ones), P the trilinear interpolation from the
coarse grid and T the force on the grabbed nodes, taken from the awake region's own solution each frame.
The operator depends on the fixed nodes and the live elements only, so it is factorised once, not per
grab (a cut builds it again: seconds on a 100k-node body; a piece cut free stops the far field, since
it has no linear answer). Measured on the 10k-node study block against the fine linear answer of a lift and shear of the
study's patch: 6 % from it beyond 10 mm of the patch with the grid of the coarse step (three mean edges),
21 % with one twice as coarse, 2 % with one two thirds as coarse. A grid driven instead by the grabbed
nodes' displacement (their jump's forces, -K_Fg jump) was 23-115 % off: the coarse grid cannot bend as
sharply as the fine mesh around the patch, so a move it is made to follow spreads too far.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from chainsim.systems.engine.kernels.twolevel import assemble_tets, tet_pattern, trilinear_weights


class FarField:
    """The coarse, linear response of a body's loose nodes to forces on its grabbed nodes."""

    def __init__(self, rest_si: np.ndarray, tets: np.ndarray, D: np.ndarray, K_e: np.ndarray, spacing: float):
        self.n = len(rest_si)
        self.tets, self.D, self.K_e, self.spacing = tets, D, K_e, spacing
        lo = rest_si.min(axis=0)
        dims = np.maximum(np.ceil((rest_si.max(axis=0) - lo) / spacing).astype(np.int64) + 1, 2)
        self.cids, self.cw = trilinear_weights(rest_si, lo, spacing, dims)
        self._ops: tuple | None = None  # (key, P, factor) for one set of live elements and fixed nodes
        self.cmap, self.weights = self.cids, np.zeros_like(self.cw)
        self.seconds = 0.0  # the last set-up's time

    def operators(self, active: np.ndarray, fixed: np.ndarray) -> None:
        """Build (once per set of live elements and fixed nodes) the factorised P^T K P of the loose
        nodes, and the coarse ids and weights per node that `follow_far` reads (zero on fixed nodes)."""
        key = (active.tobytes(), fixed.tobytes())
        if self._ops is not None and self._ops[0] == key:
            return
        t0 = time.perf_counter()
        ids = np.flatnonzero(active)
        indptr, indices = tet_pattern(self.n, self.tets, ids)
        _, k_data = assemble_tets(indptr, indices, self.tets, ids, self.D, np.zeros(len(self.tets)), self.K_e)
        K = sp.bsr_matrix((k_data, indices, indptr), shape=(3 * self.n, 3 * self.n)).tocsr()
        loose = np.flatnonzero(~fixed)
        used = np.unique(self.cids[loose])
        cmap = np.minimum(np.searchsorted(used, self.cids), len(used) - 1)
        cw = np.where(fixed[:, None], 0.0, self.cw)
        P = sp.csr_matrix((cw.ravel(), (np.repeat(np.arange(self.n), 8), cmap.ravel())), shape=(self.n, len(used)))
        P3 = sp.kron(P, sp.eye(3), format="csr")
        A = (P3.T @ (K @ P3)).tocsc()
        d = A.diagonal()
        top = max(float(d.max()), 1e-300)
        # a coarse node only fixed nodes reach has nothing to move: a unit diagonal pins it
        A = (A + sp.diags(np.where(d <= 1e-12 * top, top, 1e-10 * top))).tocsc()
        factor = splu(A, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        self._ops = (key, P.tocsr(), factor)
        self.cmap, self.weights = np.ascontiguousarray(cmap), np.ascontiguousarray(cw)
        self.seconds = time.perf_counter() - t0

    def response(self, nodes: np.ndarray, force: np.ndarray) -> np.ndarray:
        """The coarse grid's displacement (coarse nodes, 3) under `force` (len(nodes), 3) on `nodes`."""
        assert self._ops is not None
        _, P, factor = self._ops
        b = (P[nodes].T @ force).ravel()
        return np.ascontiguousarray(factor.solve(b).reshape(-1, 3))

    def at(self, nodes: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """The displacement (len(nodes), 3) the coarse grid's displacement Y gives `nodes`."""
        return np.einsum("ik,ikj->ij", self.weights[nodes], Y[self.cmap[nodes]])

"""Vectorised assembly of P1 tetrahedral stiffness matrices into scipy CSR (thesis 2.3.2, eq. 2.4).

The sparsity pattern is computed once per mesh; later assemblies (every Newton iteration of the
nonlinear solver) only scatter element values with one np.bincount.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .tetmesh import dof_indices


class SparsePattern:
    """Maps the (T, 12, 12) element blocks of a tetrahedral mesh onto one CSR matrix."""

    def __init__(self, tets: np.ndarray, n_nodes: int):
        dofs = dof_indices(tets)
        self.ndof = 3 * n_nodes
        rows = np.repeat(dofs, 12, axis=1).ravel()
        cols = np.tile(dofs, (1, 12)).ravel()
        keys = rows * self.ndof + cols
        uniq, self.inverse = np.unique(keys, return_inverse=True)
        self.rows = uniq // self.ndof
        self.cols = uniq % self.ndof
        self.indptr = np.searchsorted(self.rows, np.arange(self.ndof + 1)).astype(np.int64)
        self.nnz = len(uniq)

    def assemble(self, ke: np.ndarray) -> sp.csr_matrix:
        """ke: (T, 12, 12) element matrices in the dof order of tetmesh.dof_indices."""
        data = np.bincount(self.inverse, weights=ke.reshape(-1), minlength=self.nnz)
        return sp.csr_matrix((data, self.cols, self.indptr), shape=(self.ndof, self.ndof))


def element_matrices(vol: np.ndarray, grads: np.ndarray, tangent: np.ndarray) -> np.ndarray:
    """K_e[(a,i),(b,j)] = V * sum_kl G[a,k] A[i,k,j,l] G[b,l] for a 4th-order tangent A.

    `tangent` is (3,3,3,3) (one material) or (T,3,3,3,3) (per element, nonlinear case).
    """
    if tangent.ndim == 4:
        ke = np.einsum("tak,ikjl,tbl->taibj", grads, tangent, grads, optimize=True)
    else:
        ke = np.einsum("tak,tikjl,tbl->taibj", grads, tangent, grads, optimize=True)
    ke *= vol[:, None, None, None, None]
    return ke.reshape(len(vol), 12, 12)


def element_forces(vol: np.ndarray, grads: np.ndarray, stress: np.ndarray) -> np.ndarray:
    """Nodal internal forces f[(a,i)] = V * sum_k P[i,k] G[a,k]; stress is (T,3,3) (PK1)."""
    f = np.einsum("tik,tak->tai", stress, grads, optimize=True) * vol[:, None, None]
    return f.reshape(len(vol), 12)


def scatter_forces(tets: np.ndarray, fe: np.ndarray, n_nodes: int) -> np.ndarray:
    dofs = dof_indices(tets)
    return np.bincount(dofs.ravel(), weights=fe.ravel(), minlength=3 * n_nodes)

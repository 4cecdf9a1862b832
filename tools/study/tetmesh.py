"""Geometry of P1 tetrahedra shared by the reference solvers: volumes, shape-function gradients,
edge lists and the degenerate-element check (thesis 2.3.2, FEM on tetrahedral elements).

Everything is vectorised over elements; there is no Python loop over tetrahedra.
"""

from __future__ import annotations

import numpy as np

from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.meshgen import links_from_cells


class DegenerateElementsError(UserError):
    """Raised when some tetrahedra have (near) zero volume; `element_ids` lists them."""

    def __init__(self, element_ids: np.ndarray, rel_tol: float):
        self.element_ids = np.asarray(element_ids, dtype=np.int64)
        shown = ", ".join(str(int(i)) for i in self.element_ids[:20])
        more = f" (and {len(self.element_ids) - 20} more)" if len(self.element_ids) > 20 else ""
        super().__init__(
            f"mesh has {len(self.element_ids)} near-zero-volume tetrahedra "
            f"(|volume| < {rel_tol:g} * mean_edge^3): element ids {shown}{more}; "
            "remove or repair them before solving"
        )


def edge_matrices(pos: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T, 3, 3) matrices whose columns are x1-x0, x2-x0, x3-x0 for each tetrahedron."""
    x = pos[tets]
    return np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=2)


def mean_edge_length(pos: np.ndarray, tets: np.ndarray) -> np.ndarray:
    x = pos[tets]
    pairs = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]
    return np.mean([np.linalg.norm(x[:, a] - x[:, b], axis=1) for a, b in pairs], axis=0)


def degenerate_elements(pos: np.ndarray, tets: np.ndarray, rel_tol: float = 1e-6) -> np.ndarray:
    """Ids of tetrahedra whose volume is below rel_tol times the cube of their mean edge length.

    The threshold is scale free, so a millimetre mesh and a metre mesh are judged alike.
    """
    vol = np.abs(np.linalg.det(edge_matrices(pos, tets))) / 6.0
    h = mean_edge_length(pos, tets)
    bad = ~(vol > rel_tol * h**3)  # also catches NaN coordinates
    return np.flatnonzero(bad)


def shape_gradients(pos: np.ndarray, tets: np.ndarray, rel_tol: float = 1e-6):
    """Rest volumes (T,) and gradients of the four barycentric shape functions (T, 4, 3).

    Raises DegenerateElementsError naming the offending element ids instead of producing
    infinite gradients (which would turn into NaN displacements downstream).
    """
    pos = np.asarray(pos, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    bad = degenerate_elements(pos, tets, rel_tol)
    if len(bad):
        raise DegenerateElementsError(bad, rel_tol)
    dm = edge_matrices(pos, tets)
    vol = np.abs(np.linalg.det(dm)) / 6.0
    inv = np.linalg.inv(dm)  # rows are gradients of N1, N2, N3
    grads = np.empty((len(tets), 4, 3))
    grads[:, 1:, :] = inv
    grads[:, 0, :] = -inv.sum(axis=1)
    return vol, grads


def dof_indices(tets: np.ndarray) -> np.ndarray:
    """(T, 12) global degree-of-freedom ids ordered (node a, axis i) -> 3*tets[a] + i."""
    return (3 * np.asarray(tets, dtype=np.int64)[:, :, None] + np.arange(3)).reshape(len(tets), 12)


def tet_edges(tets: np.ndarray) -> np.ndarray:
    """Unique undirected edges of the tetrahedra (the spring network of a mass-spring model)."""

    return links_from_cells(tets)

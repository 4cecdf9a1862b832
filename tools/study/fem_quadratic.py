"""Reference solver for forces: static linear-elastic FEM on quadratic (P2, 10-node) tetrahedra.

Linear P1 tetrahedra lock as nu approaches 0.5 (thesis 2.3.2 uses P1; at nu = 0.45 the study's
1519-node cantilever is a quarter too stiff against beam theory), which matters little for the
shape of a displacement field but directly for the force a grab needs. Quadratic tetrahedra add a
node at every edge midpoint, with shape functions L_i (2 L_i - 1) at the corners and 4 L_i L_j on
the edges; their strain is linear in the element, so bending and near-incompressible states are
resolved on the same mesh. The stiffness is integrated exactly (the integrand is quadratic on a
straight-sided tetrahedron) with the 4-point degree-2 rule, assembled in chunks into scipy CSR and
solved with Dirichlet conditions by elimination (scipy SuperLU), as `fem_linear` does.

Imposed displacements are given on corner nodes; a midpoint is held when both its corners are, at
their mean (exact for the study's fixed faces and rigidly moved patches).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from chainsim.systems.engine.meshgen import links_from_cells

from .fem_linear import isotropic_tangent, lame
from .tetmesh import shape_gradients

#: the six edges of a tetrahedron, in the order of the midpoint nodes 4..9
EDGES = ((0, 1), (1, 2), (0, 2), (0, 3), (1, 3), (2, 3))
_A, _B = 0.5854101966249685, 0.1381966011250105
#: barycentric coordinates of the 4-point degree-2 rule (weights V/4 each)
QUAD_POINTS = np.array([[_A, _B, _B, _B], [_B, _A, _B, _B], [_B, _B, _A, _B], [_B, _B, _B, _A]])
CHUNK = 4096  # tetrahedra per assembly chunk: bounds the (T, 30, 30) temporary


def quadratic_mesh(pos: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corner nodes then one midpoint per unique edge: (positions (N+E, 3), tets10 (T, 10), edges (E, 2))."""
    pos = np.asarray(pos, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    edges = links_from_cells(tets)  # sorted (i < j), unique
    key = edges[:, 0] * len(pos) + edges[:, 1]
    order = np.argsort(key)
    tet_edges = np.sort(tets[:, list(EDGES)], axis=2)  # (T, 6, 2)
    k = tet_edges[..., 0] * len(pos) + tet_edges[..., 1]
    mid = order[np.searchsorted(key[order], k)] + len(pos)
    pos2 = np.concatenate([pos, 0.5 * (pos[edges[:, 0]] + pos[edges[:, 1]])])
    return pos2, np.concatenate([tets, mid], axis=1), edges


def quadratic_gradients(grads1: np.ndarray, bary: np.ndarray) -> np.ndarray:
    """Gradients (T, 10, 3) of the ten P2 shape functions at barycentric point `bary` (4,), from the
    constant P1 gradients (T, 4, 3)."""
    g = np.empty((len(grads1), 10, 3))
    for i in range(4):
        g[:, i] = (4.0 * bary[i] - 1.0) * grads1[:, i]
    for m, (i, j) in enumerate(EDGES):
        g[:, 4 + m] = 4.0 * (bary[i] * grads1[:, j] + bary[j] * grads1[:, i])
    return g


def stiffness(pos: np.ndarray, tets: np.ndarray, E: float, nu: float) -> tuple[sp.csr_matrix, np.ndarray, np.ndarray]:
    """Global P2 stiffness (3 M x 3 M), the P2 node positions (M, 3) and the 10-node tets."""
    lam, mu = lame(E, nu)
    C = isotropic_tangent(lam, mu)
    vol, grads1 = shape_gradients(pos, tets)
    pos2, tets10, _ = quadratic_mesh(pos, tets)
    ndof = 3 * len(pos2)
    K = sp.csr_matrix((ndof, ndof))
    for s in range(0, len(tets), CHUNK):
        sl = slice(s, s + CHUNK)
        ke = np.zeros((len(vol[sl]), 10, 3, 10, 3))
        for q in QUAD_POINTS:
            g = quadratic_gradients(grads1[sl], q)
            ke += np.einsum("tak,ikjl,tbl->taibj", g, C, g, optimize=True)
        ke *= (vol[sl] / 4.0)[:, None, None, None, None]
        dofs = (3 * tets10[sl][:, :, None] + np.arange(3)).reshape(-1, 30)
        rows = np.repeat(dofs, 30, axis=1).ravel()
        cols = np.tile(dofs, (1, 30)).ravel()
        K = K + sp.csr_matrix((ke.ravel(), (rows, cols)), shape=(ndof, ndof))
    return K, pos2, tets10


class QuadraticFEM:
    """Assemble and factorise once for a set of held corner nodes; `solve` imposes their displacements.

    constrained: corner node ids whose displacement is prescribed (fixed and grabbed alike).
    """

    def __init__(self, pos, tets, E: float, nu: float, constrained):
        self.pos = np.asarray(pos, dtype=np.float64)
        self.n = len(self.pos)
        self.K, self.pos2, self.tets10 = stiffness(self.pos, np.asarray(tets, dtype=np.int64), E, nu)
        _, _, self.edges = quadratic_mesh(self.pos, tets)
        c = np.unique(np.asarray(constrained, dtype=np.int64))
        held = np.zeros(len(self.pos2), dtype=np.bool_)
        held[c] = True
        both = held[self.edges[:, 0]] & held[self.edges[:, 1]]
        held[self.n :][both] = True
        self.held_nodes = np.flatnonzero(held)
        self.constrained = c
        cd = (3 * self.held_nodes[:, None] + np.arange(3)).ravel()
        mask = np.ones(self.K.shape[0], bool)
        mask[cd] = False
        self.cdofs, self.fdofs = cd, np.flatnonzero(mask)
        Kf = self.K[self.fdofs][:, self.fdofs].tocsc()
        self.K_fc = self.K[self.fdofs][:, self.cdofs].tocsr()
        self.lu = spla.splu(Kf, permc_spec="COLAMD") if len(self.fdofs) else None

    def _full_constrained(self, disp_constrained) -> np.ndarray:
        """Prescribed displacement of every held P2 node from those of the held corners."""
        u = np.zeros((len(self.pos2), 3))
        if disp_constrained is not None:
            u[self.constrained] = np.asarray(disp_constrained, dtype=np.float64).reshape(-1, 3)
        mids = self.held_nodes[self.held_nodes >= self.n]
        e = self.edges[mids - self.n]
        u[mids] = 0.5 * (u[e[:, 0]] + u[e[:, 1]])
        return u

    def solve(self, disp_constrained=None, forces=None) -> np.ndarray:
        """Displacements (M, 3) of all P2 nodes (the first N are the corner nodes, the input mesh's).

        disp_constrained: (len(constrained), 3) in np.unique(constrained) order; forces: (M, 3) loads.
        """
        u = self._full_constrained(disp_constrained).ravel()
        rhs = -(self.K_fc @ u[self.cdofs])
        if forces is not None:
            rhs += np.asarray(forces, dtype=np.float64).reshape(-1)[self.fdofs]
        if self.lu is not None:
            u[self.fdofs] = self.lu.solve(rhs)
        return u.reshape(-1, 3)

    def nodes_of(self, corner_ids) -> np.ndarray:
        """The P2 nodes on corner set `corner_ids`: the corners and the midpoints of edges inside the set."""
        inside = np.zeros(len(self.pos2), dtype=np.bool_)
        inside[np.asarray(corner_ids, dtype=np.int64)] = True
        inside[self.n :] = inside[self.edges[:, 0]] & inside[self.edges[:, 1]]
        return np.flatnonzero(inside)

    def reaction(self, u: np.ndarray, corner_ids) -> np.ndarray:
        """Total force (3,) needed on the P2 nodes of `corner_ids` to hold displacement field u: sum of K u."""
        f = (self.K @ np.asarray(u).ravel()).reshape(-1, 3)
        return f[self.nodes_of(corner_ids)].sum(axis=0)


def face_load(fem: QuadraticFEM, tets: np.ndarray, on_face, total: np.ndarray) -> np.ndarray:
    """Consistent nodal loads (M, 3) of a uniform traction with resultant `total` over the boundary faces
    whose three corners satisfy `on_face` (a mask over corner nodes). On a P2 triangle a uniform traction
    loads the corners with 0 and each edge midpoint with a third of the face's share."""
    tets = np.asarray(tets, dtype=np.int64)
    faces = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 2, 3]], tets[:, [0, 1, 3]], tets[:, [0, 1, 2]]])
    faces = np.unique(np.sort(faces[np.all(on_face[faces], axis=1)], axis=1), axis=0)
    p = fem.pos[faces]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    edge_key = fem.edges[:, 0] * fem.n + fem.edges[:, 1]
    f = np.zeros((len(fem.pos2), 3))
    share = area / area.sum()
    for i, j in ((0, 1), (1, 2), (0, 2)):
        mid = np.searchsorted(edge_key, faces[:, i] * fem.n + faces[:, j]) + fem.n
        np.add.at(f, mid, share[:, None] * np.asarray(total, dtype=np.float64)[None, :] / 3.0)
    return f

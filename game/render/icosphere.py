"""The unit icosphere the renderer draws points and markers with, built with numpy alone.

The same vertices and triangles, in the same order, as trimesh.creation.icosphere (a test compares
them), so the same pixels: importing trimesh takes most of a second, which a window's first picture
then does not wait on (chainsim.systems.engine.meshcache keeps the pack's meshes for the same reason).
"""

from __future__ import annotations

import numpy as np

_A, _B = 0.5257311121191336, 0.85065080835204
#: the icosahedron trimesh starts from (its stored primitive)
ICOSAHEDRON_VERTICES = [
    [-_A, _B, 0.0], [_A, _B, 0.0], [-_A, -_B, 0.0], [_A, -_B, 0.0], [0.0, -_A, _B], [0.0, _A, _B],
    [0.0, -_A, -_B], [0.0, _A, -_B], [_B, 0.0, -_A], [_B, 0.0, _A], [-_B, 0.0, -_A], [-_B, 0.0, _A],
]  # fmt: skip
ICOSAHEDRON_FACES = [
    [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6],
    [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10],
    [8, 6, 7], [9, 8, 1],
]  # fmt: skip


def icosphere(subdiv: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (N, 3) float64 on the unit sphere, triangles (M, 3) int64): the icosahedron split
    `subdiv` times, each new vertex pushed out onto the sphere."""
    v = np.array(ICOSAHEDRON_VERTICES, dtype=np.float64)
    f = np.array(ICOSAHEDRON_FACES, dtype=np.int64)
    for _ in range(subdiv):
        edges = np.sort(f[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
        # one midpoint per edge, numbered in trimesh's order (its row hash: second index high, first low)
        _keys, first, inverse = np.unique(edges[:, 0] + (edges[:, 1] << 32), return_index=True, return_inverse=True)
        mid = v[edges[first]].mean(axis=1)
        ab, bc, ca = (inverse.reshape(-1, 3) + len(v)).T
        a, b, c = f.T
        # four triangles per triangle, in trimesh's order and winding
        f = np.column_stack((a, ab, ca, ab, b, bc, ca, bc, c, ab, bc, ca)).reshape(-1, 3)
        v = np.vstack((v, mid))
        r = np.sqrt(np.dot(v**2, [1, 1, 1]))
        v += v / r.reshape(-1, 1) * (1.0 - r).reshape(-1, 1)
    return v, f

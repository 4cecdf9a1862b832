"""A built-in tetrahedraliser for closed surfaces: a structured tet grid of the inside cells.

Generalised ChainMail needs a volume's elements and links (thesis 5.2.6), not a quality FE mesh, so a
voxel approach is enough: lay a cubic grid over the surface's bounding box, keep the cells whose centre
is inside (trimesh's inside test), split each kept cube into the six tetrahedra of `meshgen.tet_grid`
(interior elements get 14 links, like the thesis's 7 x 7 x 7 volume of 5.3), and pull the grid nodes
that stick out of the surface back onto it, so the volume stays inside the shape it models.
"""

from __future__ import annotations

import numpy as np
import trimesh

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.meshes import MeshData, boundary_triangles

#: default number of cells along the longest side when no pitch is given
DEFAULT_CELLS = 16


class TetraError(ValueError):
    """A surface that cannot be filled (open, empty, or too fine for the requested pitch)."""


def tetrahedralize(
    mesh: MeshData,
    pitch: float | None = None,
    cells: int = DEFAULT_CELLS,
    snap: bool = True,
    max_elements: int = 2_000_000,
) -> MeshData:
    """Fill a closed triangle surface (MeshData) with a structured tet grid; returns a MeshData.

    pitch: cube size in mesh units (default: longest side / `cells`). snap: move grid nodes that lie
    outside the surface to the nearest surface point.
    """

    tri = trimesh.Trimesh(
        np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.triangles, dtype=np.int64), process=True
    )
    if len(tri.faces) == 0:
        raise TetraError("the surface has no triangles")
    if not tri.is_watertight:
        raise TetraError("the surface is not closed (watertight); only closed surfaces can be filled")
    lo, hi = tri.bounds
    size = hi - lo
    if pitch is None:
        if cells < 1:
            raise TetraError(f"cells must be >= 1, got {cells}")
        pitch = float(size.max()) / cells
    if not (pitch > 0 and np.isfinite(pitch)):
        raise TetraError(f"pitch must be a positive number, got {pitch}")
    counts = np.maximum(np.ceil(size / pitch).astype(np.int64), 1)
    nodes = counts + 1
    if int(np.prod(nodes)) > max_elements:
        raise TetraError(
            f"pitch {pitch:g} gives {int(np.prod(nodes))} grid nodes (limit {max_elements}); use a larger pitch"
        )
    origin = lo + (size - counts * pitch) / 2  # centre the grid on the shape
    ax = [origin[a] + (np.arange(counts[a]) + 0.5) * pitch for a in range(3)]
    cx, cy, cz = np.meshgrid(*ax, indexing="ij")
    centres = np.stack([cx.ravel(), cy.ravel(), cz.ravel()], axis=1)
    inside = tri.contains(centres).reshape(tuple(counts))  # [i, j, k]
    if not inside.any():
        raise TetraError(f"no grid cell of pitch {pitch:g} lies inside the surface; use a smaller pitch")
    nx, ny, nz = (int(c) for c in nodes)
    idx = meshgen.grid_index((nx, ny, nz))
    ii, jj, kk = np.nonzero(inside)
    corner = [idx[ii + i, jj + j, kk + k] for k in (0, 1) for j in (0, 1) for i in (0, 1)]
    paths = [(1, 3), (1, 5), (2, 3), (2, 6), (4, 5), (4, 6)]  # the split of meshgen.tet_grid
    tets = np.concatenate([np.stack([corner[0], corner[p], corner[q], corner[7]], 1) for p, q in paths])
    pos, _ = meshgen.grid((nx, ny, nz), pitch, 3)
    pos = pos + origin
    used = np.unique(tets)
    remap = np.full(nx * ny * nz, -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    pos = pos[used]
    tets = remap[tets]
    if snap:
        outside = ~tri.contains(pos)
        if outside.any():
            closest, _, _ = trimesh.proximity.closest_point(tri, pos[outside])
            pos[outside] = closest
    return MeshData(np.ascontiguousarray(pos), boundary_triangles(tets), tets.astype(np.int64))

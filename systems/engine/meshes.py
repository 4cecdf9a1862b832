"""Mesh data for packs: load surface files (trimesh) and tetrahedral files (meshio), or build primitives.

Everything becomes a `MeshData` in millimetres: vertices (N, 3) float64, triangles (F, 3) int64 and,
for volumes, tetrahedra (T, 4) int64. Errors name the file and what is wrong (they surface in
`chainsim validate` and at load).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import meshio
import numpy as np
import trimesh

from chainsim.engine import meshgen

SURFACE_EXT = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")
VOLUME_EXT = (".msh", ".vtk", ".vtu", ".mesh")
DEFAULT_MAX_MESH_MB = 64.0


class MeshError(Exception):
    """A mesh file that cannot be used; the message says why."""


def max_mesh_bytes() -> int:
    try:
        mb = float(os.environ.get("CHAINSIM_MAX_MESH_MB", DEFAULT_MAX_MESH_MB))
    except ValueError:
        mb = DEFAULT_MAX_MESH_MB
    return int(mb * 1024 * 1024)


@dataclass(slots=True)
class MeshData:
    vertices: np.ndarray
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    tets: np.ndarray | None = None
    links: np.ndarray | None = None  # explicit links (grids); otherwise derived from cells

    def edge_links(self) -> np.ndarray:
        """Undirected links: given ones, else tetrahedron edges, else triangle edges."""
        if self.links is not None:
            return self.links
        if self.tets is not None and len(self.tets):
            return meshgen.links_from_cells(self.tets)
        return meshgen.links_from_polygons(self.triangles)


def _check(mesh: MeshData, where: str) -> MeshData:
    v = mesh.vertices
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise MeshError(f"{where}: no vertices")
    if not np.isfinite(v).all():
        raise MeshError(f"{where}: {int((~np.isfinite(v)).any(axis=1).sum())} vertices have non-finite coordinates")
    for name, cells in (("triangles", mesh.triangles), ("tetrahedra", mesh.tets)):
        if cells is not None and len(cells) and (cells.min() < 0 or cells.max() >= len(v)):
            raise MeshError(f"{where}: {name} refer to vertices outside 0..{len(v) - 1}")
    if len(mesh.triangles) == 0 and (mesh.tets is None or len(mesh.tets) == 0) and mesh.links is None:
        raise MeshError(f"{where}: no faces or cells")
    return mesh


def load_file(path: Path, scale_to_mm: float = 1.0, merge_vertices: bool = True, label: str | None = None) -> MeshData:
    """Read a surface or tetrahedral mesh file and convert it to millimetres; `label` names it in errors."""
    path = Path(path)
    where = label or str(path)
    ext = "".join(path.suffixes[-1:]).lower()
    try:
        size = path.stat().st_size
    except OSError as e:
        raise MeshError(f"{where}: cannot read ({e.strerror})") from None
    if size > max_mesh_bytes():
        raise MeshError(f"{where}: {size / 1048576:.2f} MB is over the {max_mesh_bytes() / 1048576:.3g} MB mesh limit")
    if ext in VOLUME_EXT:
        mesh = _load_volume(path, where)
    elif ext in SURFACE_EXT:
        mesh = _load_surface(path, merge_vertices, where)
    else:
        raise MeshError(
            f"{where}: unsupported mesh type '{ext}'; expected one of {', '.join(SURFACE_EXT + VOLUME_EXT)}"
        )
    mesh.vertices = mesh.vertices * scale_to_mm
    return _check(mesh, where)


def _load_surface(path: Path, merge_vertices: bool, where: str) -> MeshData:

    try:
        loaded = trimesh.load(str(path), force="mesh", process=merge_vertices)
    except Exception as e:  # trimesh raises many types for bad files
        raise MeshError(
            f"{where}: not a readable mesh ({type(e).__name__}: {str(e).splitlines()[0] if str(e) else 'parse error'})"
        ) from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.vertices) == 0:
        raise MeshError(f"{where}: contains no triangle mesh")
    return MeshData(np.asarray(loaded.vertices, dtype=np.float64), np.asarray(loaded.faces, dtype=np.int64))


def _load_volume(path: Path, where: str) -> MeshData:

    try:
        m = meshio.read(str(path))
    except (Exception, SystemExit) as e:  # meshio calls sys.exit on some unreadable .msh files
        raise MeshError(
            f"{where}: not a readable volume mesh ({type(e).__name__}: {str(e).splitlines()[0] if str(e) else 'parse error'})"
        ) from None
    tets = [c.data for c in m.cells if c.type == "tetra"]
    tris = [c.data for c in m.cells if c.type == "triangle"]
    pts = np.asarray(m.points, dtype=np.float64)
    if pts.ndim == 2 and pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    if not tets and not tris:
        raise MeshError(f"{where}: has no tetra or triangle cells")
    t4 = np.concatenate(tets).astype(np.int64) if tets else None
    surf = (
        np.concatenate(tris).astype(np.int64)
        if tris
        else (boundary_triangles(t4) if t4 is not None else np.zeros((0, 3), np.int64))
    )
    return MeshData(pts, surf, t4)


def boundary_triangles(tets: np.ndarray) -> np.ndarray:
    """Faces used by exactly one tetrahedron, oriented outward when the tets are positively oriented."""
    faces = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]])
    key = np.sort(faces, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inv.ravel()] == 1]


def primitive(kind: str, *, extents, radius: float, height: float, resolution) -> MeshData:
    """Built-in shapes so packs can have tools and test bodies without mesh files."""

    res = [max(1, int(round(r))) for r in resolution]
    if kind == "box":
        m = trimesh.creation.box(extents=extents)
    elif kind == "sphere":
        m = trimesh.creation.uv_sphere(radius=radius, count=[max(res[0], 8), max(res[1], 8)])
    elif kind == "cylinder":
        m = trimesh.creation.cylinder(radius=radius, height=height, sections=max(res[0], 6))
    elif kind == "capsule":
        m = trimesh.creation.capsule(radius=radius, height=height, count=[max(res[0], 8), max(res[1], 8)])
    elif kind == "cone":
        m = trimesh.creation.cone(radius=radius, height=height, sections=max(res[0], 6))
    elif kind == "grid":
        nx, ny = res[0] + 1, res[1] + 1
        pos, tris, links = meshgen.triangulated_grid(nx, ny, 1.0, dim=3)
        pos[:, 0] *= extents[0] / max(nx - 1, 1)
        pos[:, 1] *= extents[1] / max(ny - 1, 1)
        pos[:, :2] -= np.asarray(extents[:2]) / 2
        return MeshData(pos, tris)
    elif kind == "tet_block":
        nx, ny, nz = res[0] + 1, res[1] + 1, max(res[2], 1) + 1
        pos, tets, _ = meshgen.tet_grid(nx, ny, nz)
        pos = pos * (np.asarray(extents) / np.maximum([nx - 1, ny - 1, nz - 1], 1)) - np.asarray(extents) / 2
        return MeshData(pos, boundary_triangles(tets), tets)
    else:
        raise MeshError(f"unknown primitive {kind!r}")
    return MeshData(np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64))

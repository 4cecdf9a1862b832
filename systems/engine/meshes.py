"""Mesh data for packs: load surface files (trimesh) and tetrahedral files (meshio), or build primitives.

Everything becomes a `MeshData` in millimetres: vertices (N, 3) float64, triangles (F, 3) int64 and,
for volumes, tetrahedra (T, 4) int64. Errors name the file and what is wrong (they surface in
`chainsim validate` and at load). Before a parser runs, the file's size and what its headers declare
are checked (chainsim.systems.engine.meshcheck); after, every vertex must be finite and within the coordinate
limit and the counts within the mesh limits (chainsim.systems.engine.limits, docs/limits.md), so a mesh never
brings an inf or a NaN into the world and a primitive's resolution can never ask for 10^10 vertices.
"""

from __future__ import annotations

import contextlib
import io
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from chainsim.systems.engine import limits, meshcache, meshcheck, meshgen
from chainsim.systems.engine.limits import max_mesh_bytes  # noqa: F401  (the mesh size limit, re-exported)

SURFACE_EXT = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")
VOLUME_EXT = (".msh", ".vtk", ".vtu", ".mesh")
DEFAULT_MAX_MESH_MB = limits.DEFAULT_MAX_MESH_MB


class MeshError(Exception):
    """A mesh file that cannot be used; the message says why."""


@dataclass(slots=True)
class MeshData:
    vertices: np.ndarray
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    tets: np.ndarray | None = None
    links: np.ndarray | None = None  # explicit links (grids); otherwise derived from cells
    # a volume file's point data `fixed` (nonzero: pinned) and cell data `layer` (per tetrahedron)
    fixed: np.ndarray | None = None
    layers: np.ndarray | None = None

    def edge_links(self) -> np.ndarray:
        """Undirected links: given ones, else tetrahedron edges, else triangle edges."""
        if self.links is not None:
            return self.links
        if self.tets is not None and len(self.tets):
            return meshgen.links_from_cells(self.tets)
        return meshgen.links_from_polygons(self.triangles)


def _check_vertices(v: np.ndarray, where: str) -> None:
    """Finite coordinates within the limit, and not too many of them."""
    if len(v) > limits.MAX_VERTICES:
        raise MeshError(f"{where}: {len(v):,} vertices, over the {limits.MAX_VERTICES:,} limit (docs/limits.md)")
    try:
        limits.coordinates(v)
    except limits.LimitError as e:
        raise MeshError(f"{where}: {str(e).replace('point(s)', 'vertices')}") from None


def _check(mesh: MeshData, where: str) -> MeshData:
    v = mesh.vertices
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise MeshError(f"{where}: no vertices")
    _check_vertices(v, where)
    for name, cells in (("triangles", mesh.triangles), ("tetrahedra", mesh.tets)):
        if cells is not None and len(cells) > limits.MAX_CELLS:
            raise MeshError(f"{where}: {len(cells):,} {name}, over the {limits.MAX_CELLS:,} limit (docs/limits.md)")
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
    limit = max_mesh_bytes()
    try:
        size = path.stat().st_size
        if not path.is_file():
            raise MeshError(f"{where}: not a file")
    except ValueError as e:  # a NUL byte in the path
        raise MeshError(f"{where!r}: not a usable path ({e})") from None
    except OSError as e:
        raise MeshError(f"{where}: cannot read ({e.strerror})") from None
    if size > limit:
        raise MeshError(f"{where}: {size / 1048576:.2f} MB is over the {limit / 1048576:.3g} MB mesh limit")
    if ext not in VOLUME_EXT + SURFACE_EXT:
        raise MeshError(
            f"{where}: unsupported mesh type '{ext}'; expected one of {', '.join(SURFACE_EXT + VOLUME_EXT)}"
        )
    try:
        meshcheck.check_file(path, ext, limit)
    except meshcheck.MeshCheckError as e:
        raise MeshError(f"{where}: {e}") from None
    data = path.read_bytes()
    name = meshcache.key(data, ext, scale_to_mm, merge_vertices)
    kept = meshcache.read(name)
    if kept is not None and kept["vertices"] is not None:
        return _check(MeshData(**{k: v for k, v in kept.items() if v is not None}), where)
    if ext in VOLUME_EXT:
        mesh = _check(_load_volume(path, where, scale_to_mm), where)
    else:
        mesh = _check(_load_surface(path, merge_vertices, where, scale_to_mm), where)
    meshcache.write(name, {f: getattr(mesh, f) for f in meshcache.FIELDS})
    return mesh


@contextlib.contextmanager
def _quiet():
    """Parsers warn (numpy casts of garbage) and print (meshio); a bad file gets our one line instead."""
    with (
        warnings.catch_warnings(),
        np.errstate(all="ignore"),
        contextlib.redirect_stdout(io.StringIO()),
        contextlib.redirect_stderr(io.StringIO()),
    ):
        warnings.simplefilter("ignore")
        yield


def _why(e: BaseException) -> str:
    text = str(e).splitlines()[0] if str(e).strip() else "parse error"
    return f"{type(e).__name__}: {text[:200]}"


def _load_surface(path: Path, merge_vertices: bool, where: str, scale: float) -> MeshData:
    import trimesh  # noqa: PLC0415 - most of a second to import; a cached mesh needs none (meshcache)

    try:
        # unprocessed first: processing silently drops NaN/inf vertices, which must be refused instead
        with _quiet():
            loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception as e:  # trimesh raises many types for bad files
        raise MeshError(f"{where}: not a readable mesh ({_why(e)})") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.vertices) == 0:
        raise MeshError(f"{where}: contains no triangle mesh")
    _check_vertices(np.asarray(loaded.vertices, dtype=np.float64) * scale, where)
    if merge_vertices:
        try:
            with _quiet():
                loaded.process()
        except Exception as e:
            raise MeshError(f"{where}: not a usable mesh ({_why(e)})") from None
    verts = np.asarray(loaded.vertices, dtype=np.float64) * scale
    return MeshData(verts, np.asarray(loaded.faces, dtype=np.int64).reshape(-1, 3))


def _load_volume(path: Path, where: str, scale: float) -> MeshData:
    import meshio  # noqa: PLC0415 - as trimesh in _load_surface

    try:
        with _quiet():
            m = meshio.read(str(path))
    except (Exception, SystemExit) as e:  # meshio calls sys.exit on some unreadable .msh files
        raise MeshError(f"{where}: not a readable volume mesh ({_why(e)})") from None
    tets = [c.data for c in m.cells if c.type == "tetra"]
    tris = [c.data for c in m.cells if c.type == "triangle"]
    fixed, layers = _volume_data(m, where)
    try:
        pts = np.asarray(m.points, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise MeshError(f"{where}: points are not numbers ({_why(e)})") from None
    if pts.ndim == 2 and pts.shape[1] == 2:
        pts = np.column_stack([pts, np.zeros(len(pts))])
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise MeshError(f"{where}: no 3-D points")
    pts = pts * scale
    _check_vertices(pts, where)
    if not tets and not tris:
        raise MeshError(f"{where}: has no tetra or triangle cells")
    if sum(len(c) for c in tets + tris) > limits.MAX_CELLS:
        raise MeshError(f"{where}: more than {limits.MAX_CELLS:,} cells (docs/limits.md)")
    t4 = np.concatenate(tets).astype(np.int64) if tets else None
    if t4 is not None and len(t4) and (t4.min() < 0 or t4.max() >= len(pts)):
        raise MeshError(f"{where}: tetrahedra refer to vertices outside 0..{len(pts) - 1}")
    surf = (
        np.concatenate(tris).astype(np.int64)
        if tris
        else (boundary_triangles(t4) if t4 is not None else np.zeros((0, 3), np.int64))
    )
    if fixed is not None and len(fixed) != len(pts):
        raise MeshError(f"{where}: point data 'fixed' has {len(fixed)} values for {len(pts)} points")
    if layers is not None and (t4 is None or len(layers) != len(t4)):
        raise MeshError(f"{where}: cell data 'layer' does not give one value per tetrahedron")
    return MeshData(pts, surf, t4, fixed=fixed, layers=layers)


def _volume_data(m, where: str) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The pinned points (point data `fixed`) and each tetrahedron's layer (cell data `layer`), if given."""
    fixed = layers = None
    try:
        if "fixed" in m.point_data:
            fixed = np.asarray(m.point_data["fixed"]).reshape(-1) != 0
        if "layer" in m.cell_data:
            blocks = [np.asarray(b).reshape(-1) for c, b in zip(m.cells, m.cell_data["layer"]) if c.type == "tetra"]
            layers = np.concatenate(blocks).astype(np.int64) if blocks else None
    except (TypeError, ValueError) as e:
        raise MeshError(f"{where}: point data 'fixed' or cell data 'layer' is not numbers ({_why(e)})") from None
    return fixed, layers


def boundary_triangles(tets: np.ndarray) -> np.ndarray:
    """Faces used by exactly one tetrahedron, oriented outward when the tets are positively oriented."""
    faces = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]])
    key = np.sort(faces, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inv.ravel()] == 1]


def check_mesh(mesh: MeshData, where: str) -> MeshData:
    """Counts, finite and bounded coordinates, cell indices in range; raises MeshError."""
    return _check(mesh, where)


def primitive_size(kind: str, resolution: Sequence[float] | np.ndarray) -> tuple[int, int]:
    """(vertices, cells) a primitive of this resolution has, computed without building it."""
    r = [max(1, int(round(min(float(x), 1e12)))) for x in resolution]
    if kind == "grid":
        return (r[0] + 1) * (r[1] + 1), 2 * r[0] * r[1]
    if kind == "tet_block":
        return (r[0] + 1) * (r[1] + 1) * (max(r[2], 1) + 1), 6 * r[0] * r[1] * max(r[2], 1)
    if kind in ("sphere", "capsule"):
        a, b = max(r[0], 8), max(r[1], 8)
        return a * b, 2 * a * b
    if kind in ("cylinder", "cone"):
        return 2 * max(r[0], 6) + 2, 4 * max(r[0], 6)
    return 8, 12


def check_primitive(kind: str, resolution: Sequence[float] | np.ndarray, where: str = "primitive") -> None:
    """Refuse a resolution whose mesh would be over MAX_VERTICES or MAX_CELLS (before building it)."""
    nv, nc = primitive_size(kind, resolution)
    if nv > limits.MAX_VERTICES or nc > limits.MAX_CELLS:
        raise MeshError(
            f"{where}: a {kind} of resolution {[int(round(float(x))) for x in resolution]} has {nv:,} vertices and "
            f"{nc:,} cells, over the limits of {limits.MAX_VERTICES:,} and {limits.MAX_CELLS:,} (docs/limits.md)"
        )


def primitive(
    kind: str,
    *,
    extents: Sequence[float] | np.ndarray,
    radius: float,
    height: float,
    resolution: Sequence[float] | np.ndarray,
) -> MeshData:
    """Built-in shapes so packs can have tools and test bodies without mesh files."""
    check_primitive(kind, resolution)
    res = [max(1, int(round(r))) for r in resolution]
    if kind in TRIMESH_SHAPES:
        spec = repr((kind, [float(x) for x in extents], float(radius), float(height), res)).encode()
        name = meshcache.key(spec, "primitive", 1.0, False)
        kept = meshcache.read(name)
        if kept is not None and kept["vertices"] is not None and kept["triangles"] is not None:
            return MeshData(kept["vertices"], kept["triangles"])
        mesh = _trimesh_shape(kind, extents, radius, height, res)
        meshcache.write(name, {"vertices": mesh.vertices, "triangles": mesh.triangles})
        return mesh
    if kind == "grid":
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
    raise MeshError(f"unknown primitive {kind!r}")


#: the primitives trimesh makes (kept by meshcache: a later start imports no trimesh for them)
TRIMESH_SHAPES = ("box", "sphere", "cylinder", "capsule", "cone")


def _trimesh_shape(kind: str, extents, radius: float, height: float, res: list[int]) -> MeshData:
    import trimesh  # noqa: PLC0415 - as in _load_surface

    if kind == "box":
        m = trimesh.creation.box(extents=extents)
    elif kind == "sphere":
        m = trimesh.creation.uv_sphere(radius=radius, count=[max(res[0], 8), max(res[1], 8)])
    elif kind == "cylinder":
        m = trimesh.creation.cylinder(radius=radius, height=height, sections=max(res[0], 6))
    elif kind == "capsule":
        m = trimesh.creation.capsule(radius=radius, height=height, count=[max(res[0], 8), max(res[1], 8)])
    else:
        m = trimesh.creation.cone(radius=radius, height=height, sections=max(res[0], 6))
    return MeshData(np.asarray(m.vertices, np.float64), np.asarray(m.faces, np.int64))

"""Deformable bodies (Generalised ChainMail, thesis 5.2) and scripted pullers, as ECS components.

`deformable` is the switch that makes a mesh entity soft: at spawn its build hook turns the entity's
render mesh into a ChainMail object (elements = mesh vertices in the SAME order, links = triangle edges
for a surface or tetrahedron edges for a volume, 5.2.1 and 5.2.6) with per-link material limits taken
from a [materials] entry and optional inline overrides. An entity whose `simulation.kind` is "surface"
or "volume" but has no `deformable` table gets a default one from `chainsim.systems.deformation` (same fields,
material = the mesh's material), so both spellings lead to one component.

Runtime state lives in the same dataclass: `rest` and `pos` (N, 3) in the entity's local frame, the
link graph, per-link limits, the fixed mask, the cascade workspace, `dirty` (ids moved since the
renderer last uploaded; the renderer replaces it with an empty array after uploading) and `version`.
Of the runtime state only `pos`, `version`, `alive` (cut links) and `held` count towards the world
digest; the rest is derived from the pack or is render bookkeeping and is marked digest-neutral.

`pull` scripts a pull on one element (the thesis 5.3 demos): when triggered (at a time, or by a
widget event), the element is dragged along a path of waypoints at a constant speed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import esper
import numpy as np

from chainsim.components.core import MeshRef
from chainsim.components.registry import component, prop
from chainsim.engine import meshgen
from chainsim.engine.errors import UserError
from chainsim.engine.kernels.chainmail import make_workspace, material_arrays
from chainsim.engine.kernels.graph import build_graph

ORDERS = ("fifo", "balanced", "schill")
SOURCES = ("auto", "surface", "volume")
INHERIT = -1.0  # an inline material value of -1 means "take it from the material"

#: [materials] defaults when an entity names no material (the manifest's own defaults)
DEFAULT_MATERIAL = {"alpha_min": 0.8, "alpha_max": 1.2, "beta": 0.1, "relax": 2}


def _nodigest(factory):
    return field(default_factory=factory, metadata={"digest": False})


def _empty_ids():
    return np.zeros(0, dtype=np.int64)


def build_deformable(d: Deformable, ctx) -> None:
    """Spawn hook: derive the ChainMail object from the entity's mesh (see `setup_deformable`)."""

    where = f"entities.{ctx.entity_name}.deformable"
    mesh_ref = esper.try_component(ctx.entity, MeshRef)
    if mesh_ref is None:
        raise UserError(f"{where}: a deformable entity needs a mesh table ([entities.{ctx.entity_name}.mesh])")
    setup_deformable(d, ctx.pack.mesh(mesh_ref.mesh), ctx.pack.section("materials"), mesh_ref.material, where)


@component(
    "deformable",
    help="Soft body: ChainMail on the entity's mesh (thesis 5.2). Needs a mesh table.",
    build=build_deformable,
)
@dataclass(slots=True)
class Deformable:
    material: str = prop(
        "str", "", help="[materials] entry with alpha_min/alpha_max/beta/relax (default: the mesh's material)."
    )
    source: str = prop(
        "enum",
        "auto",
        choices=SOURCES,
        help="surface: links are triangle edges; volume: tetrahedron edges; auto: volume when the mesh has tetrahedra.",
    )
    alpha_min: float = prop("float", INHERIT, help="Compression limit override, 0..1 (-1: from the material).")
    alpha_max: float = prop("float", INHERIT, help="Stretch limit override, >= 1 (-1: from the material).")
    beta: float = prop("float", INHERIT, help="Shear limit override, >= 0 (-1: from the material).")
    relax: int = prop("int", -1, help="Relaxation iterations after each cascade, thesis 5.2.5 (-1: from the material).")
    relax_step: float = prop(
        "float", 1.0, help="Fraction of the way to the relaxed position per iteration.", min=0.0, max=1.0
    )
    fixed: np.ndarray = prop("int_list", [], help="Element (vertex) ids that never move.")
    fixed_box: np.ndarray = prop(
        "float_list",
        [],
        units="mm",
        help="Elements inside this local box never move: [xmin, ymin, zmin, xmax, ymax, zmax] (empty: none).",
    )
    fixed_boundary: bool = prop(
        "bool", False, help="Pin the open rim of a surface (vertices on edges used by one triangle)."
    )
    order: str = prop(
        "enum",
        "fifo",
        choices=ORDERS,
        help="Waiting-list order: fifo (5.2.3), balanced (round robin of Fig. 5.3), schill (largest violation first).",
    )
    depth: int = prop("int", 2, help="Branch depth per turn for the balanced order.", min=1)
    dtype: str = prop("enum", "float64", choices=("float64", "float32"), help="Precision of positions.")
    drag: bool = prop(
        "bool",
        False,
        help="A mouse drag on the body pulls the element nearest the grab point "
        "(off when a procedure's tools do the grabbing).",
    )

    # --- runtime state (not manifest keys) -----------------------------------------------------
    pos: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    version: int = 0
    alive: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.bool_))
    held: np.ndarray = field(default_factory=_empty_ids)
    rest: np.ndarray = _nodigest(lambda: np.zeros((0, 3)))
    graph: object = field(default=None, metadata={"digest": False})
    amin: np.ndarray = _nodigest(lambda: np.zeros(0))
    amax: np.ndarray = _nodigest(lambda: np.zeros(0))
    beta_l: np.ndarray = _nodigest(lambda: np.zeros(0))
    fixed_mask: np.ndarray = _nodigest(lambda: np.zeros(0, dtype=np.bool_))
    relax_iterations: int = field(default=0, metadata={"digest": False})
    workspace: object = field(default=None, metadata={"digest": False})
    dirty: np.ndarray = _nodigest(_empty_ids)
    last_order: np.ndarray = _nodigest(_empty_ids)
    last_sponsor: np.ndarray = _nodigest(_empty_ids)
    _dirty_mask: np.ndarray = _nodigest(lambda: np.zeros(0, dtype=np.bool_))
    _dirty_seen: object = field(default=None, metadata={"digest": False})

    @property
    def n_elements(self) -> int:
        return int(self.pos.shape[0])

    def mark_dirty(self, ids: np.ndarray) -> None:
        """Union `ids` into `dirty` (cost follows len(ids), not N)."""
        if self._dirty_seen is not self.dirty:
            # the renderer replaced `dirty` after uploading: forget what it has already seen
            if self._dirty_seen is not None and len(self._dirty_seen):
                self._dirty_mask[self._dirty_seen] = False
            if len(self.dirty):
                self._dirty_mask[self.dirty] = True
        ids = np.asarray(ids, dtype=np.int64)
        new = np.unique(ids[~self._dirty_mask[ids]])
        if len(new):
            self._dirty_mask[new] = True
            self.dirty = np.concatenate([self.dirty, new])
        self._dirty_seen = self.dirty


def resolve_material(d: Deformable, materials: dict, mesh_material: str, where: str) -> dict:
    """alpha_min/alpha_max/beta/relax from the named material and the inline overrides; checked."""
    name = d.material or mesh_material
    if name:
        if name not in materials:
            known = ", ".join(sorted(materials)) or "none"
            raise UserError(f"{where}.material: no material '{name}' in [materials] (known: {known})")
        base = {k: materials[name].get(k, v) for k, v in DEFAULT_MATERIAL.items()}
    else:
        base = dict(DEFAULT_MATERIAL)
    for key in ("alpha_min", "alpha_max", "beta"):
        v = getattr(d, key)
        if v != INHERIT:
            base[key] = float(v)
    if d.relax != -1:
        base["relax"] = int(d.relax)
    if not (0.0 <= base["alpha_min"] <= 1.0):
        raise UserError(f"{where}.alpha_min: must be in [0, 1], got {base['alpha_min']:g}")
    if not (base["alpha_max"] >= 1.0):
        raise UserError(f"{where}.alpha_max: must be >= 1, got {base['alpha_max']:g}")
    if not (base["beta"] >= 0.0):
        raise UserError(f"{where}.beta: must be >= 0, got {base['beta']:g}")
    if base["relax"] < 0:
        raise UserError(f"{where}.relax: must be >= 0 (or -1 for the material's), got {base['relax']}")
    return base


def body_links(mesh, source: str, where: str) -> np.ndarray:
    """Links of the ChainMail object for `source` (surface edges or tetrahedron edges)."""

    has_tets = mesh.tets is not None and len(mesh.tets) > 0
    if source == "auto":
        source = "volume" if has_tets else "surface"
    if mesh.links is not None:
        return np.asarray(mesh.links, dtype=np.int64)
    if source == "volume":
        if not has_tets:
            raise UserError(
                f"{where}.source: 'volume' needs a mesh with tetrahedra (a .msh/.vtu/.vtk/.mesh file or "
                f"the tet_block primitive); this mesh has only triangles"
            )
        return meshgen.links_from_cells(mesh.tets)
    if len(mesh.triangles) == 0:
        raise UserError(f"{where}.source: 'surface' needs a mesh with triangles")
    return meshgen.links_from_polygons(mesh.triangles)


def boundary_vertices(triangles: np.ndarray) -> np.ndarray:
    """Vertices on edges that belong to exactly one triangle (the rim of an open surface)."""
    if len(triangles) == 0:
        return _empty_ids()
    e = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]]), axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    return np.unique(uniq[counts == 1].ravel())


def setup_deformable(
    d: Deformable, mesh, materials: dict, mesh_material: str = "", where: str = "deformable"
) -> Deformable:
    """Fill the runtime state of `d` from a MeshData (positions copied; the pack's mesh is shared)."""

    mat = resolve_material(d, materials, mesh_material, where)
    dtype = np.float32 if d.dtype == "float32" else np.float64
    verts = np.ascontiguousarray(mesh.vertices, dtype=dtype)
    n = len(verts)
    links = body_links(mesh, d.source, where)
    graph = build_graph(n, links)
    amin, amax, beta = material_arrays(graph.n_links, mat["alpha_min"], mat["alpha_max"], mat["beta"], dtype=np.float64)
    fixed = np.zeros(n, dtype=np.bool_)
    ids = np.asarray(d.fixed, dtype=np.int64)
    if len(ids):
        if ids.min() < 0 or ids.max() >= n:
            raise UserError(f"{where}.fixed: element ids must be in 0..{n - 1}, got {int(ids.min())}..{int(ids.max())}")
        fixed[ids] = True
    box = np.asarray(d.fixed_box, dtype=np.float64)
    if len(box):
        if box.shape != (6,) or np.any(box[:3] > box[3:]):
            raise UserError(f"{where}.fixed_box: expected [xmin, ymin, zmin, xmax, ymax, zmax] with min <= max")
        fixed |= np.all((verts >= box[:3]) & (verts <= box[3:]), axis=1)
    if d.fixed_boundary:
        fixed[boundary_vertices(np.asarray(mesh.triangles, dtype=np.int64))] = True
    d.rest = verts.copy()
    d.pos = verts.copy()
    d.graph = graph
    d.alive = graph.alive  # the same array the kernels read: cutting flips it in place
    d.amin, d.amax, d.beta_l = amin, amax, beta
    d.fixed_mask = fixed
    d.relax_iterations = int(mat["relax"])
    d.workspace = make_workspace(n)
    d.dirty = _empty_ids()
    d._dirty_mask = np.zeros(n, dtype=np.bool_)
    d._dirty_seen = d.dirty
    d.held = _empty_ids()
    d.version = 0
    return d


def build_pull(p: Pull, ctx) -> None:
    """Spawn hook: check the path; the element is resolved once the deformable exists."""
    where = f"entities.{ctx.entity_name}.pull"
    pts = np.asarray(p.path, dtype=np.float64)
    if len(pts) == 0 or len(pts) % 3:
        raise UserError(
            f"{where}.path: expected a flat list of x, y, z waypoints (3 numbers each), got {len(pts)} numbers"
        )
    p.waypoints = pts.reshape(-1, 3)


@component(
    "pull", help="Scripted pull on one element of this entity's deformable (thesis 5.3 demos).", build=build_pull
)
@dataclass(slots=True)
class Pull:
    path: np.ndarray = prop(
        "float_list",
        units="mm",
        help="Waypoints x0,y0,z0, x1,y1,z1, ...: the element is dragged from its rest position through them.",
    )
    element: int = prop("int", -1, help="Element (vertex) id pulled; -1: the element nearest to `at`.", min=-1)
    at: np.ndarray = prop(
        "vec3", (0.0, 0.0, 0.0), units="mm", help="Point near the pulled element when `element` is -1."
    )
    frame: str = prop("enum", "local", choices=("local", "world"), help="Frame of `path` and `at`.")
    speed: float = prop("float", 20.0, units="mm/s", help="Speed along the path.", min=1e-9)
    start: float = prop(
        "float", 0.0, units="s", help="Simulated time the pull starts (ignored when `widget` is set).", min=0.0
    )
    widget: str = prop("str", "", help="Start when this widget event arrives (e.g. a 'pull' button or script event).")
    hold: bool = prop("bool", True, help="Keep holding the element at the end of the path.")
    # runtime state
    started: bool = False
    done: bool = False
    travelled: float = 0.0
    resolved: int = -1
    start_at: np.ndarray = field(default_factory=lambda: np.zeros(3))
    waypoints: np.ndarray = _nodigest(lambda: np.zeros((0, 3)))

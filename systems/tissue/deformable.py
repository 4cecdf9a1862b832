"""Deformable bodies (Generalised ChainMail, thesis 5.2) and scripted pullers, as ECS components.

`deformable` is the switch that makes a mesh entity soft: at spawn its build hook turns the entity's
render mesh into a ChainMail object (elements = mesh vertices in the SAME order, links = triangle edges
for a surface or tetrahedron edges for a volume, 5.2.1 and 5.2.6) with per-link material limits taken
from a [materials] entry and optional inline overrides. An entity whose `simulation.kind` is "surface"
or "volume" but has no `deformable` table gets a default one from `chainsim.systems.tissue.deformation` (same fields,
material = the mesh's material), so both spellings lead to one component.

The component holds the pack's keys and one handle, `body`: the soft body built at spawn
(chainsim.systems.engine.bodies.soft), which owns the runtime state: the rest shape and positions (N, 3)
in the entity's local frame, the link graph and per-link limits, the fixed mask, the held elements,
`version` and the ids moved since the renderer last took them. Of that state only the positions,
`version`, the alive links and the held elements count towards the world digest (`digest_items`); the
rest derives from the pack or is render bookkeeping.

`pull` scripts a pull on one element (the thesis 5.3 demos): when triggered (at a time, or by a
widget event), the element is dragged along a path of waypoints at a constant speed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import esper
import numpy as np

from chainsim.assets import ASSETS_DIR
from chainsim.components.core import MeshRef
from chainsim.components.registry import component, prop
from chainsim.components.resources import Settings
from chainsim.systems.engine import limits, meshgen, model_params
from chainsim.systems.engine.bodies.chainmail import ChainMailBody, link_limits
from chainsim.systems.engine.bodies.factory import choose_model, load_table, make_body
from chainsim.systems.engine.bodies.soft import SoftBody
from chainsim.systems.engine.chainmail_params import ORDER_CHOICES, order_name
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels.graph import Graph, build_graph
from chainsim.systems.engine.model_params import manifest_spec

ORDERS = ORDER_CHOICES  # breadth-first, balanced, schill, depth-first; fifo = breadth-first
MODEL_CHOICES = (*model_params.MODELS, "auto")
#: the speed-accuracy table `model = "auto"` chooses from (written by `chainsim study speed-accuracy`)
MODEL_TABLE = ASSETS_DIR / "presets" / "models.toml"
SOURCES = ("auto", "surface", "volume")
INHERIT = -1.0  # an inline material value of -1 means "take it from the material"

#: [materials] defaults when an entity names no material (the manifest's own defaults, model_params)
DEFAULT_MATERIAL = {k: model_params.params("chainmail")[k].manifest_default for k in model_params.MATERIAL_KEYS}
#: the ChainMail body's own defaults (where a material gives none)
CHAINMAIL_DEFAULTS = model_params.defaults("chainmail")
#: a volume model's settings, shared by the models that take them (named in each key's help)
ELASTIC_MODELS = ("xpbd", "projective", "hybrid")


def _pack_only(*args, **kw):
    """A manifest key left out of the world digest: like the limits it sets (amin, amax, beta_l), it is
    derived from the pack, and packs that do not use it keep the digests they had."""
    f = prop(*args, **kw)
    return field(default_factory=f.default_factory, metadata={**f.metadata, "digest": False})


def _model_prop(name: str, models: tuple[str, ...], prefix: bool = True):
    """A manifest key declared once, with the models' parameters (chainsim.systems.engine.model_params)."""
    spec = manifest_spec(name, models, prefix=prefix)
    return prop(spec.pop("kind"), spec.pop("default"), **spec)


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
    override = ctx.app.resource(Settings).get("model", "") if ctx.app is not None else ""
    setup_deformable(
        d, ctx.pack.mesh(mesh_ref.mesh), ctx.pack.section("materials"), mesh_ref.material, where, model=override
    )


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
    relax: int = prop(
        "int",
        -1,
        help="Relaxation iterations after each cascade, thesis 5.2.5 (-1: from the material).",
        min=-1,
        max=limits.MAX_RELAX,
    )
    relax_step: float = _model_prop("relax_step", ("chainmail",), prefix=False)
    regions: list = _pack_only(
        "str_list",
        [],
        help="[materials] entries for parts of the body (layers, regions), one per box of `region_boxes`: a link "
        "whose midpoint lies in a box takes that material's alpha_min, alpha_max and beta (a later box wins); "
        "relax and exact stay the body's.",
    )
    region_boxes: np.ndarray = _pack_only(
        "float_list",
        [],
        units="mm",
        help="One local box per entry of `regions`: [xmin, ymin, zmin, xmax, ymax, zmax, ...].",
        stride=6,
    )
    fixed: np.ndarray = prop(
        "int_list", [], help="Element (vertex) ids that never move.", min=0, max=limits.MAX_VERTICES - 1
    )
    fixed_box: np.ndarray = prop(
        "float_list",
        [],
        units="mm",
        help="Elements inside this local box never move: [xmin, ymin, zmin, xmax, ymax, zmax] (empty: none).",
    )
    fixed_boundary: bool = prop(
        "bool", False, help="Pin the open rim of a surface (vertices on edges used by one triangle)."
    )
    order: str = _model_prop("order", ("chainmail",), prefix=False)
    depth: int = _model_prop("depth", ("chainmail",), prefix=False)
    dtype: str = _model_prop("dtype", ("chainmail",), prefix=False)
    drag: bool = prop(
        "bool",
        False,
        help="A mouse drag on the body pulls the element nearest the grab point "
        "(off when a procedure's tools do the grabbing).",
    )
    model: str = prop(
        "enum",
        "chainmail",
        choices=MODEL_CHOICES,
        help="Deformation model: chainmail (thesis 5.2), xpbd, projective (volumes only), surface (SurfaceChainMail "
        "on a sheet, thesis 4.4), or auto "
        "(the cheapest meeting error_budget / time_budget_ms in the study's table).",
    )
    E: float = _model_prop("E", ELASTIC_MODELS)
    nu: float = _model_prop("nu", ELASTIC_MODELS)
    density: float = _model_prop("density", ELASTIC_MODELS)
    damping: float = _model_prop("damping", ("xpbd", "projective"))
    substeps: int = _model_prop("substeps", ("xpbd",))
    iterations: int = _model_prop("iterations", ("xpbd", "projective", "hybrid"))
    solver: str = _model_prop("solver", ("projective",))
    cg_iterations: int = _model_prop("cg_iterations", ("projective",))
    rotation_iterations: int = _model_prop("rotation_iterations", ("projective",))
    unit: float = _model_prop("unit", ELASTIC_MODELS)
    thickness: float = _model_prop("thickness", ("xpbd", "projective"))
    error_budget: float = prop(
        "float", 0.0, help="auto: largest RMS error / imposed displacement allowed (0: no limit).", min=0.0, max=10.0
    )
    time_budget_ms: float = prop("float", 0.0, units="ms", help="auto: CPU per update allowed (0: none).", min=0.0)

    # --- runtime state (not a manifest key) ------------------------------------------------------
    # the soft body: positions, links, limits and what readers see. Built by the spawn hook
    # (setup_deformable), so every spawned component has one; None only on a component not yet set up
    body: SoftBody = field(default=None, metadata={"digest": False})  # type: ignore[assignment]

    def digest_items(self) -> tuple[tuple[str, Any], ...]:
        """The body's state that counts towards the world digest (components.digest): its positions,
        version, alive links and held elements; the rest derives from the pack or is render bookkeeping."""
        b = self.body
        if b is None:
            return (
                ("pos", np.zeros((0, 3))),
                ("version", 0),
                ("alive", np.zeros(0, dtype=np.bool_)),
                ("held", _empty_ids()),
            )
        return (("pos", b.positions), ("version", b.version), ("alive", b.alive), ("held", b.held))


def _named_material(materials: dict, name: str, where: str) -> dict:
    if name not in materials:
        known = ", ".join(sorted(materials)) or "none"
        raise UserError(f"{where}: no material '{name}' in [materials] (known: {known})")
    return {k: materials[name].get(k, v) for k, v in DEFAULT_MATERIAL.items()}


def _check_limits(mat: dict, where: str) -> None:
    """The ChainMail limits of `mat` against their declaration (chainsim.systems.engine.model_params)."""
    decl = model_params.params("chainmail")
    for key in ("alpha_min", "alpha_max", "beta"):
        decl[key].check(mat[key], f"{where}.")


def resolve_material(d: Deformable, materials: dict, mesh_material: str, where: str) -> dict:
    """alpha_min/alpha_max/beta/relax/exact from the named material and the inline overrides; checked."""
    name = d.material or mesh_material
    base = _named_material(materials, name, f"{where}.material") if name else dict(DEFAULT_MATERIAL)
    for key in ("alpha_min", "alpha_max", "beta"):
        v = getattr(d, key)
        if v != INHERIT:
            base[key] = float(v)
    if d.relax != -1:
        base["relax"] = int(d.relax)
    _check_limits(base, where)
    if base["relax"] < 0:
        raise UserError(f"{where}.relax: must be >= 0 (or -1 for the material's), got {base['relax']}")
    return base


def resolve_regions(d: Deformable, materials: dict, where: str) -> list[tuple[np.ndarray, dict]]:
    """(box, material) for each entry of `regions`, in order; checked."""
    boxes = np.asarray(d.region_boxes, dtype=np.float64)
    if len(boxes) != 6 * len(d.regions):
        raise UserError(
            f"{where}.region_boxes: expected one box of 6 numbers per region ({len(d.regions)} regions), "
            f"got {len(boxes)} numbers"
        )
    out = []
    for k, name in enumerate(d.regions):
        box = boxes[6 * k : 6 * k + 6]
        if np.any(box[:3] > box[3:]):
            raise UserError(f"{where}.region_boxes: box {k} needs [xmin, ymin, zmin, xmax, ymax, zmax] with min <= max")
        mat = _named_material(materials, name, f"{where}.regions[{k}]")
        _check_limits(mat, f"{where}.regions[{k}]")
        out.append((box, mat))
    return out


def material_limits(links: np.ndarray, verts: np.ndarray, spec: tuple) -> tuple[np.ndarray, ...]:
    """Per-link (amin, amax, beta) for `links` from `spec` = (material, regions): the material's limits
    (link_limits), and in each region's box (by link midpoint, later regions winning) the region material's."""
    mat, regions = spec
    m = len(links)
    amin, amax, beta = link_limits(m, *(float(mat[k]) for k in model_params.PER_LINK))
    if regions and m:
        mid = 0.5 * (np.asarray(verts[links[:, 0]], np.float64) + np.asarray(verts[links[:, 1]], np.float64))
        for box, rmat in regions:
            inside = np.all((mid >= box[:3]) & (mid <= box[3:]), axis=1)
            amin[inside], amax[inside], beta[inside] = rmat["alpha_min"], rmat["alpha_max"], rmat["beta"]
    return amin, amax, beta


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
    d: Deformable, mesh, materials: dict, mesh_material: str = "", where: str = "deformable", model: str = ""
) -> Deformable:
    """Build the soft body of `d` from a MeshData (positions copied; the pack's mesh is shared)."""

    mat = resolve_material(d, materials, mesh_material, where)
    dtype = np.float32 if d.dtype == "float32" else np.float64
    verts: np.ndarray = np.ascontiguousarray(mesh.vertices, dtype=dtype)
    n = len(verts)
    links = body_links(mesh, d.source, where)
    graph = build_graph(n, links)
    # the per-link limits, built once here: every ChainMail body of this component gets these arrays
    spec = (mat, resolve_regions(d, materials, where))
    per_link = material_limits(graph.links, verts, spec)
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
    if getattr(mesh, "fixed", None) is not None:  # a volume file's own pinned points (its point data)
        fixed |= mesh.fixed
    if d.fixed_boundary:
        fixed[boundary_vertices(np.asarray(mesh.triangles, dtype=np.int64))] = True
    d.order = order_name(d.order)  # fifo is stored as breadth-first
    rest = verts.copy()  # the body's own: `verts` may be the pack's array
    d.body = SoftBody(
        rest, mesh, links, fixed, per_link, relax_iterations=int(mat["relax"]), exact=bool(mat["exact"]), material=spec
    )
    use_model(d, model or d.model, where, graph=graph)
    return d


def chainmail_body(d: Deformable, graph: Graph | None = None) -> ChainMailBody:
    """A ChainMail body from the soft body's rest shape, links and per-link limits (the arrays themselves,
    as setup_deformable built them), on `graph` (the links as built at spawn) or a new graph of every
    link alive."""
    soft = d.body
    body = make_body(
        "chainmail",
        soft.rest,
        links=soft.links if graph is None else graph,
        fixed=soft.fixed,
        alpha_min=soft.base_limits[0],
        alpha_max=soft.base_limits[1],
        beta=soft.base_limits[2],
        relax=soft.relax_iterations,
        relax_step=d.relax_step,
        order=d.order,
        depth=d.depth,
        exact=soft.exact,
        dtype=d.dtype,
    )
    assert isinstance(body, ChainMailBody)
    return body


def surface_limits(d: Deformable, triangles: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per-link limits for a SurfaceChainMail body, whose links are the triangles' edges: the body's
    own arrays where its links are those edges, else the same material and regions on the sheet's links."""
    soft = d.body
    links = meshgen.links_from_cells(np.asarray(triangles, dtype=np.int64))
    amin, amax, beta = soft.limits
    if len(amin) == len(links) and np.array_equal(links, soft.links):
        return amin, amax, beta
    return material_limits(links, soft.rest, soft.material)


def auto_scene(d: Deformable, volume: bool) -> str:
    """The study scene an auto body is looked up in: tissue-sized volumes (under half a metre across)
    in the surgical-scale block, larger volumes in the 1 m block, surfaces in the sheet."""
    if not volume:
        return "sheet"
    rest = d.body.rest
    extent = float(np.ptp(rest, axis=0).max()) * d.unit if len(rest) else 0.0
    return "tissue-block" if extent < 0.5 else "block"


def _auto_choice(d: Deformable, volume: bool) -> tuple[str, dict, str]:
    """The model, its table row's settings and the reason `auto` picks them for `d`."""
    choice = choose_model(
        load_table(MODEL_TABLE),
        scene=auto_scene(d, volume),
        nodes=d.body.n,
        error_budget=d.error_budget,
        time_budget_ms=d.time_budget_ms,
        E=d.E,
    )
    return choice.model, choice.params, f"auto: {choice.model} ({choice.setting}), {choice.reason}"


def use_model(d: Deformable, model: str, where: str = "deformable", graph: Graph | None = None) -> None:
    """Put `d`'s body under `model` from its rest shape. `graph`: the first body at spawn, a ChainMail
    body on the links built there; without it this is a switch at run time and everything is redrawn."""
    if model not in MODEL_CHOICES:
        raise UserError(f"{where}.model: expected one of {', '.join(MODEL_CHOICES)}, got {model!r}")
    soft = d.body
    mesh = soft.mesh
    tets = mesh.tets if mesh.tets is not None and len(mesh.tets) else None
    reason = ""
    row: dict = {}
    if model == "auto":
        model, row, reason = _auto_choice(d, tets is not None)
    body: Any
    if model == "chainmail":
        if row:  # the row's material and relaxation, as the study measured them
            first = [a[0] if len(a) else CHAINMAIL_DEFAULTS[k] for k, a in zip(model_params.PER_LINK, soft.base_limits)]
            soft.base_limits = link_limits(
                len(soft.links), *(float(row.get(k, v)) for k, v in zip(model_params.PER_LINK, first))
            )
            soft.relax_iterations = int(row.get("relax", soft.relax_iterations))
        body = chainmail_body(d, graph)
    else:
        settings = _elastic_settings(d, model)
        settings.update(row)  # an auto choice builds exactly the row's setting
        body = _elastic_body(d, model, tets, settings, where)
        # the positions array the body solves in, as every model's first frame has it
        body.positions = np.array(soft.rest, dtype=np.float64)
    notice = getattr(body, "notice", "")  # what a frame will cost here, said where the choice is
    why = (reason or f"{model} (as the pack or --model asks)") + (f"; {notice}" if notice else "")
    soft.adopt(body, model, why)
    soft.model_reason += _one_material_note(d)
    if graph is None:  # a switch at run time: everything is redrawn
        soft.changed()


def _elastic_settings(d: Deformable, model: str) -> dict[str, Any]:
    """The settings the pack's keys give a body of `model` other than ChainMail."""
    soft = d.body
    settings: dict[str, Any] = {
        "E": d.E,
        "nu": d.nu,
        "density": d.density,
        "damping": d.damping,
        "unit": d.unit,
        "thickness": d.thickness,
    }
    if model == "xpbd":
        settings.update(substeps=d.substeps or "auto", iterations=d.iterations or 1)
    elif model == "surface":  # SurfaceChainMail with the material's per-link limits (thesis 4.4)
        amin, amax, beta = surface_limits(d, soft.mesh.triangles)
        settings.update(
            alpha_min=amin, alpha_max=amax, beta=beta, relax=soft.relax_iterations, exact=soft.exact, order=d.order
        )
    elif model == "hybrid":  # one two-level iteration a frame (chainsim.systems.engine.bodies.hybrid)
        settings.update(iterations=d.iterations or 1)
    else:
        settings.update(
            iterations=d.iterations or 10,
            solver=d.solver,
            cg_iterations=d.cg_iterations,
            rotation_iterations=d.rotation_iterations,
        )
    return settings


def _elastic_body(d: Deformable, model: str, tets: np.ndarray | None, settings: dict, where: str) -> Any:
    """A body of `model` from the rest shape, with its materials per element if a feature gave some."""
    soft = d.body
    try:
        body = make_body(
            model, soft.rest.astype(np.float64), tets=tets, triangles=soft.mesh.triangles, fixed=soft.fixed, **settings
        )
    except UserError as e:
        raise UserError(f"{where}: {e}") from None
    if len(soft.element_E) and hasattr(body, "set_materials") and tets is not None:
        body.set_materials(soft.element_E, soft.element_nu)
    return body


def set_element_materials(d: Deformable, E: np.ndarray, nu: np.ndarray, where: str) -> None:
    """Give `d`'s tetrahedra their own E (Pa) and nu, kept across model switches: the projective and
    hybrid bodies take them in their elastic energy; ChainMail has no moduli, and XPBD keeps the body's
    E and nu (model_reason says so)."""
    soft = d.body
    tets = soft.mesh.tets
    if tets is None or len(E) != len(tets) or len(nu) != len(tets):
        raise UserError(f"{where}: materials per element need one E and one nu per tetrahedron of the mesh")
    soft.element_E = np.asarray(E, dtype=np.float64).copy()
    soft.element_nu = np.asarray(nu, dtype=np.float64).copy()
    body = soft.model_body
    if hasattr(body, "set_materials") and not getattr(body, "surface", True):
        try:
            body.set_materials(soft.element_E, soft.element_nu)
        except UserError as e:
            raise UserError(f"{where}: {e}") from None
    else:
        soft.model_reason += _one_material_note(d)


def _one_material_note(d: Deformable) -> str:
    """What model_reason adds when the body has materials per element that its model does not take."""
    soft = d.body
    if len(soft.element_E) and soft.model_used == "xpbd" and "one E and nu" not in soft.model_reason:
        return "; xpbd keeps one E and nu for the whole body (per-element moduli: projective, hybrid)"
    return ""


def build_pull(p: Pull, ctx) -> None:
    """Spawn hook: check the path; the element is resolved once the deformable exists."""
    where = f"entities.{ctx.entity_name}.pull"
    pts = np.asarray(p.path, dtype=np.float64)
    if len(pts) == 0 or len(pts) % 3:
        raise UserError(
            f"{where}.path: expected a flat list of x, y, z waypoints (3 numbers each), got {len(pts)} numbers"
        )
    p.waypoints = pts.reshape(-1, 3)
    if p.element >= 0:  # checked at spawn (so `validate` reports it), not when the pull starts
        mesh_ref = esper.try_component(ctx.entity, MeshRef)
        if mesh_ref is not None:
            n = len(ctx.pack.mesh(mesh_ref.mesh).vertices)
            if p.element >= n:
                raise UserError(f"{where}.element: {p.element} is not an element id of the mesh (0..{n - 1})")


@component(
    "pull", help="Scripted pull on one element of this entity's deformable (thesis 5.3 demos).", build=build_pull
)
@dataclass(slots=True)
class Pull:
    path: np.ndarray = prop(
        "float_list",
        units="mm",
        help="Waypoints x0,y0,z0, x1,y1,z1, ...: the element is dragged from its rest position through them.",
        stride=3,
    )
    element: int = prop(
        "int",
        -1,
        help="Element (vertex) id pulled; -1: the element nearest to `at`.",
        min=-1,
        max=limits.MAX_VERTICES - 1,
    )
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

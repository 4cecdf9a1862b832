"""The needle meets soft tissue: tenting, puncture per layer, shaft friction and the forces, without remeshing.

Stage: simulation, after the needle collision (bone still stops the needle there) and before the
deformation system that moves the bodies. Reads: NeedleState, the pack's [needle_tissue] and
[tissue_layers.NAME] tables, the tissue bodies (Deformable, their meshes' cell data `layer`). Writes:
NeedleTissue (on the needle entity: what is punctured, held, felt), the bodies' grabs; emits
TissueEvent; appends a row to NeedleTrace every frame.

The interaction follows the constraint-based needle models of the field (SOFA's needle plugins after
Duriez et al. 2009; iMSTK's needle example) with Okamura et al.'s force split (needle_force):

- The needle's line is intersected once per pose with the layer boundaries of the tissue's rest shape
  (the skin face, then every face between tetrahedra of two layers), giving the crossings in order.
- Before the tip punctures a boundary it presses it: the boundary's crossed face is held at its rest
  place moved `tent` mm along the needle, and the tip feels the layer's punch stiffness times tent.
  At the layer's `puncture_N` the boundary gives: an event `puncture:LAYER`, the face springs back.
- A punctured boundary's face is attached to the shaft (a constraint point): it follows the needle
  as it moves (stick) until the elastic pull exceeds the layer's static friction over the length
  inserted in it, then slips back to the dynamic level (stick-slip), so the tissue is dragged in on
  insertion and out on withdrawal; turning the needle moves the attached tissue with it.
- Withdrawn past a boundary: `exit:LAYER`; out of the skin everything lets go, and the holes stay:
  re-entering within `hole_radius_mm` of one needs no new puncture (a re-entry), elsewhere it does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import Transform, to_world
from chainsim.components.hud import HudState
from chainsim.components.registry import Field, section
from chainsim.components.resources import EntityIndex, PackResource, RunOutputs
from chainsim.components.stages import ORDER_COLLISION
from chainsim.systems.engine import needle_force
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures.needle.collision import NeedleHit
from chainsim.systems.procedures.needle.components import Needle, NeedleState
from chainsim.systems.procedures.needle.manifest import NeedleScene
from chainsim.systems.tissue import deformation
from chainsim.systems.tissue.deformable import Deformable, set_element_materials

ORDER_NEEDLE_TISSUE = ORDER_COLLISION + 50

section(
    "needle_tissue",
    "table",
    "The soft tissue a needle procedure's needle meets (docs/needle-procedures.md, 'Tissue layers').",
    [
        Field(
            "bodies",
            "str_list",
            [],
            help="Deformable entities the needle can enter ({side} allowed); their meshes' cell data `layer` "
            "numbers each tetrahedron's layer.",
        ),
        Field(
            "contact_radius_mm",
            "float",
            2.0,
            units="mm",
            help="Radius over which the tissue under the tip carries load before a puncture (the punch of "
            "the stiffness term).",
            min=0.05,
            max=50.0,
        ),
        Field(
            "hole_radius_mm",
            "float",
            1.0,
            units="mm",
            help="A re-entry this close to an earlier hole in a boundary goes through it without a puncture.",
            min=0.0,
            max=50.0,
        ),
        Field(
            "stick_band_mm_s",
            "float",
            0.5,
            units="mm/s",
            help="Below this speed the shaft sticks (static friction); above it, it slides.",
            min=0.0,
            max=1000.0,
        ),
    ],
)

section(
    "tissue_layers",
    "named",
    "One layer of a needle pack's tissue: its mesh number, material and needle-force parameters, each with its source.",
    [
        Field("mesh_layer", "int", help="The layer number in the tissue meshes' cell data `layer`.", min=1, max=1000),
        Field("E_kPa", "float", help="Young's modulus (small strain).", units="kPa", min=0.01, max=1e6),
        Field("nu", "float", 0.45, help="Poisson's ratio.", min=0.0, max=0.4999),
        Field(
            "puncture_N",
            "float",
            help="Axial force at which the tip punctures the layer.",
            units="N",
            min=1e-4,
            max=100.0,
        ),
        Field(
            "cutting_N",
            "float",
            0.0,
            help="Force to cut through the layer at the tip.",
            units="N",
            min=0.0,
            max=100.0,
        ),
        Field(
            "friction_static_N_per_mm",
            "float",
            0.0,
            units="N/mm",
            help="Largest friction per mm of shaft in the layer while sticking.",
            min=0.0,
            max=10.0,
        ),
        Field(
            "friction_dynamic_N_per_mm",
            "float",
            0.0,
            units="N/mm",
            help="Friction per mm of shaft in the layer while sliding.",
            min=0.0,
            max=10.0,
        ),
        Field(
            "friction_viscous_Ns_per_mm2",
            "float",
            0.0,
            units="N s/mm2",
            help="Friction per mm of shaft per mm/s of speed while sliding.",
            min=0.0,
            max=10.0,
        ),
        Field("source", "str", "", help="Where the values come from (shown in the pack's docs)."),
    ],
)


@dataclass(frozen=True, slots=True)
class TissueEvent:
    """`kind`: contact, puncture, exit or reentry; `layer` the layer entered or left; depth along the needle."""

    kind: str
    layer: str
    depth_mm: float


@dataclass(slots=True)
class Layers:
    """The pack's layers, in mesh-number order, as arrays the force model reads."""

    names: list[str]
    number: np.ndarray  # mesh_layer of each
    E: np.ndarray
    nu: np.ndarray
    puncture: np.ndarray
    cutting: np.ndarray
    static: np.ndarray
    dyn: np.ndarray
    visc: np.ndarray

    def index(self, mesh_layer: int) -> int:
        hit = np.nonzero(self.number == mesh_layer)[0]
        return int(hit[0]) if len(hit) else -1


@dataclass(slots=True)
class TissueBody:
    """One tissue body's boundaries in its rest shape (world mm): faces and the layer behind each side."""

    entity: int
    name: str
    faces: np.ndarray  # (F, 3) node ids
    sides: np.ndarray  # (F, 2) layer index (into Layers) on each side, -1 outside the tissue
    normals: np.ndarray  # (F, 3) from sides[:, 0] towards sides[:, 1]
    rest_world: np.ndarray
    # each boundary's nodes that are free to move, by the (lower, higher) layer index on its two sides
    boundary_nodes: dict = field(default_factory=dict)


@dataclass(slots=True)
class NeedleTissueScene:
    """Resource: the layers, bodies and settings, read once."""

    layers: Layers
    bodies: list[TissueBody]
    contact_radius: float
    hole_radius: float
    stick_band: float


@dataclass(slots=True)
class Crossing:
    body: int  # index into NeedleTissueScene.bodies
    depth: float  # along the needle from the entry, rest shape
    nodes: np.ndarray  # the crossed face's node ids
    point: np.ndarray  # rest crossing point (world)
    layer_in: int  # layer entered going deeper
    layer_out: int  # layer left going deeper (-1: outside)
    room: float = np.inf  # tissue behind it along the line before the line leaves the body (mm)
    # the boundary's nodes the tip presses before it gives: the punch of the force model (see _patch)
    patch: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


@dataclass(slots=True)
class NeedleTissue:
    """Runtime state on the needle entity (in the world digest, so a replay reproduces it)."""

    pose: tuple = ()  # (entry, q) the crossings were computed for
    crossings: list = field(default_factory=list)
    punctured: int = 0  # crossings passed through so far (the first ones)
    contact: bool = False
    contact_depth: float = 0.0
    tent: float = 0.0
    offsets: np.ndarray = field(default_factory=lambda: np.zeros(0))  # per punctured crossing: drag (mm)
    holes: list = field(default_factory=list)  # (body, point, layer_in) of boundaries punctured
    last_depth: float = 0.0
    axial: float = 0.0
    lateral: float = 0.0
    terms: tuple = (0.0, 0.0, 0.0)
    peak_axial: float = 0.0
    punctures: dict = field(default_factory=dict)  # per layer name
    repunctures: int = 0  # skin punctured again at a new place
    reentries: int = 0
    held: dict = field(default_factory=dict)  # body index -> node ids held last frame
    held_at: dict = field(default_factory=dict)  # body index -> their targets (world mm)
    # what the last frame's holds and skin_tent were worked out from (NeedleTissueSystem._hold): caches,
    # not state, so left out of the world digest
    hold_key: tuple = field(default=(), metadata={"digest": False})
    tent_key: tuple = field(default=(), metadata={"digest": False})
    tip_layer: str = ""
    beyond: bool = False  # the tip is past the far side of the tissue
    skin_tent: float = 0.0
    pop: str = ""  # the last layer that gave, shown until pop_until (simulated s)
    pop_until: float = 0.0


@dataclass(slots=True)
class NeedleTrace:
    """Resource: one row per frame for needle_trace.csv."""

    rows: list = field(default_factory=list)

    # the fixed columns first (docs/needle-procedures.md), then the axial force's three terms
    HEADER = "time_s,tip_depth_mm,axial_N,lateral_N,layer,event,skin_tent_mm,stiffness_N,cutting_N,friction_N"

    def csv(self) -> str:
        lines = [self.HEADER]
        for t, depth, ax, lat, layer, event, tent, (f_s, f_c, f_f) in self.rows:
            lines.append(
                f"{t:.6f},{depth:.4f},{ax:.5f},{lat:.5f},{layer},{event},{tent:.4f},{f_s:.5f},{f_c:.5f},{f_f:.5f}"
            )
        return "\n".join(lines) + "\n"


# -- reading the pack -----------------------------------------------------------------------------


def read_layers(pack) -> Layers:
    spec = pack.section("tissue_layers")
    if not spec:
        raise UserError(f"pack '{pack.name}': [needle_tissue] needs at least one [tissue_layers.NAME]")
    items = sorted(spec.items(), key=lambda kv: int(kv[1]["mesh_layer"]))
    nums = [int(v["mesh_layer"]) for _, v in items]
    if len(set(nums)) != len(nums):
        raise UserError(f"pack '{pack.name}': tissue_layers: two layers share a mesh_layer number")
    col = lambda k: np.array([float(v[k]) for _, v in items])  # noqa: E731
    return Layers(
        [k for k, _ in items], np.array(nums), col("E_kPa"), col("nu"), col("puncture_N"), col("cutting_N"),
        col("friction_static_N_per_mm"), col("friction_dynamic_N_per_mm"), col("friction_viscous_Ns_per_mm2"),
    )  # fmt: skip


def boundaries(tets: np.ndarray, tet_layer: np.ndarray, rest: np.ndarray) -> tuple[np.ndarray, ...]:
    """Faces where the layer changes (or the tissue ends), with the layer index on each side and a
    normal from side 0 to side 1. Outer faces have -1 on the outside."""
    faces = np.concatenate([tets[:, [1, 2, 3]], tets[:, [0, 3, 2]], tets[:, [0, 1, 3]], tets[:, [0, 2, 1]]])
    owner = np.tile(np.arange(len(tets)), 4)
    key = np.sort(faces, axis=1)
    order = np.lexsort(key.T[::-1])
    key, faces, owner = key[order], faces[order], owner[order]
    same = np.all(key[1:] == key[:-1], axis=1)
    out_f, out_s = [], []
    n = len(key)
    pair = np.zeros(n, dtype=bool)
    pair[:-1] |= same
    pair[1:] |= same
    # interior faces: two owners; keep those whose layers differ
    first = np.nonzero(same)[0]
    la, lb = tet_layer[owner[first]], tet_layer[owner[first + 1]]
    diff = la != lb
    out_f.append(faces[first[diff]])  # oriented outward from owner first[diff]: side 0 is that owner
    out_s.append(np.stack([la[diff], lb[diff]], axis=1))
    # outer faces: one owner; outward oriented, so side 0 is the tissue, side 1 outside
    single = ~pair
    out_f.append(faces[single])
    out_s.append(np.stack([tet_layer[owner[single]], np.full(single.sum(), -1)], axis=1))
    f = np.concatenate(out_f)
    s = np.concatenate(out_s)
    a, b, c = rest[f[:, 0]], rest[f[:, 1]], rest[f[:, 2]]
    nrm = np.cross(b - a, c - a)
    nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
    # faces point outward from side 0's tetrahedron: the normal goes from side 0 to side 1
    return f, s, nrm


def _boundary_nodes(faces: np.ndarray, sides: np.ndarray, pinned: np.ndarray) -> dict:
    """The unpinned nodes of each boundary, keyed by the (lower, higher) layer index on its sides."""
    key = np.sort(sides, axis=1)
    out = {}
    for pair in np.unique(key, axis=0):
        nodes = np.unique(faces[np.all(key == pair, axis=1)])
        out[(int(pair[0]), int(pair[1]))] = nodes[~pinned[nodes]]
    return out


def _patch(body: TissueBody, face: int, point: np.ndarray, radius: float) -> np.ndarray:
    """The nodes a tip pressing the boundary at `point` holds: the crossed face's and every free node of
    the same boundary within `radius` (the force model's flat punch of contact_radius_mm), so the press
    is spread over the punch's area as the stiffness term assumes, not over one face of the mesh."""
    a, b = sorted(int(x) for x in body.sides[face])
    nodes = body.boundary_nodes.get((a, b), np.zeros(0, dtype=np.int64))
    near = nodes[np.linalg.norm(body.rest_world[nodes] - point, axis=1) <= radius]
    return np.union1d(body.faces[face], near)


def read_scene(app: App) -> NeedleTissueScene | None:
    pack = app.resource(PackResource).pack
    table = pack.section("needle_tissue")
    if not table or not table.get("bodies"):
        return None
    layers = read_layers(pack)
    sides = pack.section("needle_procedure").get("sides", []) or [""]
    index: EntityIndex = app.resource(EntityIndex)
    bodies = []
    with app.active():
        for pattern in table["bodies"]:
            for name in dict.fromkeys(pattern.replace("{side}", s) for s in sides):
                ent = index.get(name)
                d = esper.try_component(ent, Deformable) if ent is not None else None
                if ent is None or d is None or d.body is None or d.body.mesh.tets is None:
                    raise UserError(f"needle_tissue.bodies: '{name}' is not a deformable tetrahedral entity")
                mesh = d.body.mesh
                if mesh.layers is None:
                    raise UserError(f"needle_tissue.bodies: '{name}': its mesh has no cell data 'layer'")
                if len(mesh.layers) and int(mesh.layers.min()) < 1:
                    raise UserError(f"needle_tissue.bodies: '{name}': its cell data 'layer' must be 1 or more")
                idx = np.array([layers.index(int(x)) for x in range(int(mesh.layers.max()) + 1)])
                missing = sorted(set(np.unique(mesh.layers).tolist()) - set(layers.number.tolist()))
                if missing:
                    raise UserError(
                        f"tissue_layers: '{name}' has tetrahedra of mesh layer {missing[0]} but no "
                        f"[tissue_layers.NAME] has mesh_layer = {missing[0]}"
                    )
                # the body's elastic energy takes each layer's own modulus (kPa in the table)
                li = idx[mesh.layers]
                set_element_materials(d, layers.E[li] * 1e3, layers.nu[li], f"tissue_layers ('{name}')")
                rest = to_world(esper.try_component(ent, Transform), d.body.rest.astype(np.float64))
                f, s, nrm = boundaries(mesh.tets, idx[mesh.layers], rest)
                bodies.append(TissueBody(ent, name, f, s, nrm, rest, _boundary_nodes(f, s, d.body.fixed)))
    in_meshes = {int(x) for b in bodies for x in np.unique(b.sides) if x >= 0}
    for i, name in enumerate(layers.names):
        if i not in in_meshes:
            raise UserError(
                f"tissue_layers.{name}.mesh_layer: no tetrahedron of {', '.join(b.name for b in bodies)} has layer "
                f"{int(layers.number[i])}; expected one of the meshes' cell data `layer` values"
            )
    return NeedleTissueScene(
        layers, bodies, float(table["contact_radius_mm"]), float(table["hole_radius_mm"]),
        float(table["stick_band_mm_s"]),
    )  # fmt: skip


# -- geometry ------------------------------------------------------------------------------------------


def ray_crossings(scene: NeedleTissueScene, entry: np.ndarray, d: np.ndarray, reach: float) -> list[Crossing]:
    """Where the needle's line (from `reach` behind `entry`, onwards) crosses the layer boundaries."""
    out = []
    exits: list[tuple[int, float]] = []
    o = entry - reach * d
    for bi, body in enumerate(scene.bodies):
        p = body.rest_world
        a, b, c = p[body.faces[:, 0]], p[body.faces[:, 1]], p[body.faces[:, 2]]
        e1, e2 = b - a, c - a
        h = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, h)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = o - a
        u = inv * np.einsum("ij,ij->i", s, h)
        q = np.cross(s, e1)
        v = inv * (q @ d)
        t = inv * np.einsum("ij,ij->i", e2, q)
        eps = 1e-6  # a line through a node or an edge meets its faces at their borders
        hit = ok & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (t >= 0)
        for fi in np.nonzero(hit)[0]:
            going_in = float(body.normals[fi] @ d) < 0  # against the normal: from side 1 into side 0
            lin, lout = (body.sides[fi, 0], body.sides[fi, 1]) if going_in else (body.sides[fi, 1], body.sides[fi, 0])
            if lin < 0:
                exits.append((bi, float(t[fi]) - reach))
                continue  # leaving the tissue at its far side
            depth = float(t[fi]) - reach
            if lout < 0:
                # the entry point is on the skin: a skin face the needle's line meets just behind it (the
                # volume's skin face is a chord of the skin surface) is met at the entry itself
                depth = max(depth, 0.0)
            point = o + t[fi] * d
            patch = _patch(body, int(fi), point, scene.contact_radius)
            out.append(Crossing(bi, depth, body.faces[fi].copy(), point, int(lin), int(lout), patch=patch))
    out.sort(key=lambda c: c.depth)
    for c in out:
        beyond = [x for b, x in exits if b == c.body and x > c.depth + 1e-9]
        if beyond:
            c.room = min(beyond) - c.depth
    # one crossing per place: a line through an edge or a node meets two or more faces there
    kept: list[Crossing] = []
    for c in out:
        if kept and abs(c.depth - kept[-1].depth) < 1e-6 and c.layer_in == kept[-1].layer_in:
            continue
        kept.append(c)
    return kept


# -- the system ------------------------------------------------------------------------------------------

#: the pressed face moves with the tip through at most this share of the tissue behind it
TENT_ROOM = 0.5
#: how long (simulated s) the gauge says which layer gave way
POP_SECONDS = 1.0
#: how far behind the entry the needle's line is tested (an entry point a little inside the skin)
REACH_BACK = 10.0


def _stiffness(scene: NeedleTissueScene, layer: int) -> float:
    L = scene.layers
    return needle_force.punch_stiffness(float(L.E[layer]), float(L.nu[layer]), scene.contact_radius)


def _pose_key(st: NeedleState) -> tuple:
    return (tuple(np.round(st.entry, 9)), tuple(np.round(st.q, 12)))


def _lengths(nt: NeedleTissue, n_layers: int, depth: float) -> np.ndarray:
    """Shaft length (mm) in each layer: from each punctured crossing to the next one, the tip, or where the
    line leaves the tissue."""
    out = np.zeros(n_layers)
    for i in range(nt.punctured):
        c = nt.crossings[i]
        end = nt.crossings[i + 1].depth if i + 1 < nt.punctured else depth
        out[c.layer_in] += max(0.0, min(end, depth, c.depth + c.room) - c.depth)
    return out


def _beyond(nt: NeedleTissue, depth: float) -> bool:
    """The tip has passed through the far side of the tissue (past the last boundary's room)."""
    if not nt.punctured:
        return False
    c = nt.crossings[nt.punctured - 1]
    return depth > c.depth + c.room


def _name(scene: NeedleTissueScene, layer: int) -> str:
    return scene.layers.names[layer] if layer >= 0 else ""


def _near_hole(nt: NeedleTissue, c: Crossing, radius: float) -> bool:
    for body, point, layer in nt.holes:
        if body == c.body and layer == c.layer_in and float(np.linalg.norm(point - c.point)) <= radius:
            return True
    return False


class NeedleTissueSystem:
    """The per-frame interaction (module docstring); one instance per App."""

    def __init__(self, app: App, scene: NeedleTissueScene) -> None:
        self.scene = scene
        self.hits = app.events.reader(NeedleHit)
        # the gauge's full scale: twice the largest puncture force, so a pop happens mid-scale or above
        self.full_scale = 2.0 * float(scene.layers.puncture.max())

    def __call__(self, app: App) -> None:
        roles = app.resource(NeedleScene).roles
        bone = any(h.role in roles and roles[h.role].kind == "obstacle" for h in self.hits.read())
        dt = app.time.dt
        trace: NeedleTrace = app.resource(NeedleTrace)
        for ent, (_needle, st) in esper.get_components(Needle, NeedleState):
            nt = esper.try_component(ent, NeedleTissue)
            if nt is None:
                nt = NeedleTissue()
                esper.add_component(ent, nt)
            events = self.step(app, nt, st, dt)
            if bone:
                events.append("bone")
            self._gauge(app, nt, events, st.placed)
            tip = st.depth - nt.contact_depth if nt.contact else 0.0
            trace.rows.append(
                (
                    app.time.sim_time, max(tip, 0.0), nt.axial, nt.lateral, nt.tip_layer, ";".join(events),
                    nt.skin_tent, nt.terms,
                )
            )  # fmt: skip
            break  # one needle

    def _gauge(self, app: App, nt: NeedleTissue, events: list[str], placed: bool) -> None:
        """The force gauge over the tip view once the needle is placed; a layer giving way shows as a pop
        for POP_SECONDS."""
        hud = app.get_resource(HudState)
        if hud is None:
            return
        if not placed:
            hud.force_gauge = ()
            return
        pops = [e.partition(":")[2] for e in events if e.startswith("puncture:")]
        if pops:
            nt.pop, nt.pop_until = "pop: " + ", ".join(pops), app.time.sim_time + POP_SECONDS
        pop = nt.pop if app.time.sim_time < nt.pop_until else ""
        caption = f"tip in {nt.tip_layer}" if nt.tip_layer else ("pressing the skin" if nt.tent > 0 else "")
        hud.force_gauge = (nt.axial, nt.lateral, self.full_scale, caption, pop)

    # -- one frame for one needle ------------------------------------------------------------
    def step(self, app: App, nt: NeedleTissue, st: NeedleState, dt: float) -> list[str]:
        scene = self.scene
        events: list[str] = []
        if not st.placed:
            self._let_go(app, nt, everything=True)
            nt.last_depth = 0.0
            nt.axial = nt.lateral = 0.0
            return events
        d = st.direction()
        key = _pose_key(st)
        if key != nt.pose and nt.punctured == 0 and not nt.contact:
            nt.crossings = ray_crossings(scene, st.entry, d, REACH_BACK)
            nt.pose = key
        depth = float(st.depth)
        v = (depth - nt.last_depth) / dt
        move = depth - nt.last_depth
        if nt.crossings:
            self._withdraw(app, nt, depth, events)
            self._advance(nt, depth, events)
            beyond = _beyond(nt, depth)
            if beyond and not nt.beyond:  # out through the far side of the modelled tissue
                events.append(f"exit:{_name(scene, nt.crossings[nt.punctured - 1].layer_in)}")
            nt.beyond = beyond
        lengths = _lengths(nt, len(scene.layers.names), depth)  # shaft in each layer, read by both below
        self._drag(nt, lengths, move)
        self._forces(nt, depth, lengths, v, move > 1e-12)
        self._hold(app, nt, st, d, depth)
        nt.last_depth = depth
        nt.peak_axial = max(nt.peak_axial, nt.axial)
        for e in events:
            kind, _, layer = e.partition(":")
            app.events.emit(TissueEvent(kind, layer, depth))
        return events

    def _advance(self, nt: NeedleTissue, depth: float, events: list[str]) -> None:
        scene = self.scene
        first = nt.crossings[0]
        if not nt.contact and depth > first.depth + 1e-6:
            nt.contact, nt.contact_depth = True, first.depth
            events.append("contact")
        nt.tent = 0.0
        while nt.punctured < len(nt.crossings):
            c = nt.crossings[nt.punctured]
            if depth <= c.depth:
                break
            if _near_hole(nt, c, scene.hole_radius):
                nt.reentries += 1
                self._pass(nt, c)
                continue
            tent = depth - c.depth
            press = needle_force.press_force(_stiffness(scene, c.layer_in), tent, c.room)
            if press < scene.layers.puncture[c.layer_in]:
                nt.tent = tent
                break
            name = _name(scene, c.layer_in)
            events.append(f"puncture:{name}")
            # the boundary gave when the press reached its threshold, within this frame
            nt.peak_axial = max(nt.peak_axial, float(scene.layers.puncture[c.layer_in]))
            if c.layer_out < 0 and nt.punctures.get(name, 0) > 0:
                nt.repunctures += 1
            nt.punctures[name] = nt.punctures.get(name, 0) + 1
            nt.holes.append((c.body, c.point.copy(), c.layer_in))
            self._pass(nt, c)

    def _pass(self, nt: NeedleTissue, c: Crossing) -> None:
        nt.punctured += 1
        nt.offsets = np.append(nt.offsets, 0.0)

    def _withdraw(self, app: App, nt: NeedleTissue, depth: float, events: list[str]) -> None:
        while nt.punctured > 0 and depth <= nt.crossings[nt.punctured - 1].depth:
            c = nt.crossings[nt.punctured - 1]
            events.append(f"exit:{_name(self.scene, c.layer_in)}")
            nt.punctured -= 1
            nt.offsets = nt.offsets[: nt.punctured]
        if nt.contact and depth <= nt.crossings[0].depth:
            nt.contact = False
            nt.tent = 0.0
            self._let_go(app, nt, everything=False)

    def _drag(self, nt: NeedleTissue, lengths: np.ndarray, move: float) -> None:
        """Stick-slip of each constraint point: carried by the needle until its pull exceeds static friction."""
        L = self.scene.layers
        for i in range(nt.punctured):
            c = nt.crossings[i]
            k = _stiffness(self.scene, c.layer_in)
            length = max(lengths[c.layer_in], 0.0)
            o = nt.offsets[i] + move
            if k * abs(o) > L.static[c.layer_in] * length:
                o = np.sign(o) * L.dyn[c.layer_in] * length / k
            nt.offsets[i] = o

    def _forces(self, nt: NeedleTissue, depth: float, lengths: np.ndarray, v: float, advancing: bool) -> None:
        scene, L = self.scene, self.scene.layers
        k_tent = cutting = 0.0
        room = np.inf
        if nt.punctured < len(nt.crossings) and nt.tent > 0:
            k_tent = _stiffness(scene, nt.crossings[nt.punctured].layer_in)
            room = nt.crossings[nt.punctured].room
        tip = nt.crossings[nt.punctured - 1].layer_in if nt.punctured and not _beyond(nt, depth) else -1
        nt.tip_layer = _name(scene, tip)
        if tip >= 0:
            cutting = float(L.cutting[tip])
        stick = sum(_stiffness(scene, nt.crossings[i].layer_in) * nt.offsets[i] for i in range(nt.punctured))
        total, f_s, f_c, f_f = needle_force.evaluate(
            nt.tent, k_tent, room, advancing and tip >= 0 and nt.tent == 0.0, cutting, lengths, L.dyn, L.visc, L.static,
            v, scene.stick_band, stick,
        )  # fmt: skip
        nt.axial, nt.terms = total, (f_s, f_c, f_f)

    def _hold(self, app: App, nt: NeedleTissue, st: NeedleState, d: np.ndarray, depth: float) -> None:
        """Grab the pressed face and the constraint points where the needle puts them; let go of the rest."""
        # the holds follow from the needle's pose, depth, drag and tent alone: under a still needle (most
        # of a session's frames) they are the last frame's, and only the skin's tent is read again
        key = (st.entry.tobytes(), st.q.tobytes(), depth, nt.punctured, nt.offsets.tobytes(), nt.tent, nt.pose)
        if key != nt.hold_key:
            self._place_holds(app, nt, st, d)
            nt.hold_key = key
        nt.skin_tent = self._skin_tent(app, nt)

    def _place_holds(self, app: App, nt: NeedleTissue, st: NeedleState, d: np.ndarray) -> None:
        """Work out where the needle holds each body's nodes and grab them there (only what changed)."""
        scene = self.scene
        want: dict[int, tuple[list, list]] = {}
        lateral = np.zeros(3)
        for i in range(min(nt.punctured, len(nt.crossings))):
            c = nt.crossings[i]
            body = scene.bodies[c.body]
            # where the needle now holds this point: dragged along, by at most TENT_ROOM of the layer behind
            # it, so held boundaries never crush the layers between them
            gap = min(c.room, nt.crossings[i + 1].depth - c.depth if i + 1 < len(nt.crossings) else np.inf)
            drag = float(np.clip(nt.offsets[i], -TENT_ROOM * gap, TENT_ROOM * gap))
            shaft = st.entry + (c.depth + drag) * d
            move = shaft - c.point
            ids, targets = want.setdefault(c.body, ([], []))
            ids.extend(c.nodes.tolist())
            targets.extend((body.rest_world[c.nodes] + move).tolist())
            along = float(move @ d)
            lateral += _stiffness(scene, c.layer_in) * (move - along * d)
        if nt.tent > 0 and nt.punctured < len(nt.crossings):
            c = nt.crossings[nt.punctured]
            body = scene.bodies[c.body]
            ids, targets = want.setdefault(c.body, ([], []))
            ids.extend(c.patch.tolist())
            # the patch goes with the tip, but never more than TENT_ROOM of the tissue behind it (the force
            # model's stiffening makes it give before that in all but the softest tissue)
            targets.extend((body.rest_world[c.patch] + min(nt.tent, TENT_ROOM * c.room) * d).tolist())
        nt.lateral = float(np.linalg.norm(lateral))
        with app.active():
            for bi, body in enumerate(scene.bodies):
                dcomp = esper.try_component(body.entity, Deformable)
                if dcomp is None:
                    continue
                old = nt.held.get(bi, np.zeros(0, dtype=np.int64))
                ids, targets = want.get(bi, ([], []))
                ids_a = np.asarray(ids, dtype=np.int64)
                if len(ids_a):
                    ids_a, first = np.unique(ids_a, return_index=True)
                    tw = np.asarray(targets, dtype=np.float64)[first]
                    last = nt.held_at.get(bi)
                    # a grab that changes nothing is not made again: a body starts over on every new grab
                    if last is None or not np.array_equal(old, ids_a) or not np.array_equal(last, tw):
                        gone = np.setdiff1d(old, ids_a)
                        if len(gone):
                            deformation.release(dcomp, gone)
                        deformation.grab(dcomp, ids_a, deformation.to_local(body.entity, tw, "world"), hold=True)
                    nt.held_at[bi] = tw
                elif len(old):
                    deformation.release(dcomp, old)
                    nt.held_at.pop(bi, None)
                nt.held[bi] = ids_a

    def _skin_tent(self, app: App, nt: NeedleTissue) -> float:
        """How far the crossed skin face under the tip has moved from rest (mm), 0 without contact."""
        if not (nt.crossings and nt.contact):
            return 0.0
        c = nt.crossings[0]
        body = self.scene.bodies[c.body]
        with app.active():
            dcomp = esper.try_component(body.entity, Deformable)
            if dcomp is None:
                return 0.0
            tf = esper.try_component(body.entity, Transform)
            # a body's version changes with every step that moves it: a resting skin is not read again
            key = (
                nt.pose,
                c.body,
                dcomp.body.version,
                None if tf is None else (tf.position.tobytes(), tf.rotation.tobytes(), tf.scale),
            )
            if key == nt.tent_key:
                return nt.skin_tent
            now = to_world(tf, dcomp.body.positions[c.nodes])
        nt.tent_key = key
        return float(np.linalg.norm((now - body.rest_world[c.nodes]).mean(axis=0)))

    def _let_go(self, app: App, nt: NeedleTissue, everything: bool) -> None:
        with app.active():
            for bi, ids in list(nt.held.items()):
                dcomp = esper.try_component(self.scene.bodies[bi].entity, Deformable)
                if dcomp is not None and len(ids):
                    deformation.release(dcomp, ids)
                nt.held[bi] = np.zeros(0, dtype=np.int64)
                nt.held_at.pop(bi, None)
        nt.hold_key = nt.tent_key = ()
        nt.punctured = 0
        nt.offsets = np.zeros(0)
        nt.tent = 0.0
        nt.contact = False
        nt.skin_tent = 0.0
        nt.pose = ()
        if everything:
            nt.holes = []


def plugin(app: App) -> None:
    """Install the needle-tissue interaction when the pack has [needle_tissue] bodies."""
    scene = read_scene(app)
    if scene is None:
        return
    app.insert_resource(scene)
    trace = NeedleTrace()
    app.insert_resource(trace)
    outputs = app.get_resource(RunOutputs)
    if outputs is None:
        outputs = RunOutputs()
        app.insert_resource(outputs)
    outputs.files["needle_trace.csv"] = trace.csv
    app.add_system("simulation", NeedleTissueSystem(app, scene), order=ORDER_NEEDLE_TISSUE, name="needle_tissue")

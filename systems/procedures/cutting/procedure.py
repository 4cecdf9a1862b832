"""The cutting trainer (thesis 4.5.2): forceps pull and push layered tissue, scissors cut it along a path.

`plugin(app)` is what `pack.procedure = "cutting"` installs. The pack provides deformable layers (each
a ChainMail surface with one edge fixed), one entity with a `forceps` table and one with a `scissors`
table; the procedure never deforms tissue itself, it asks `chainsim.systems.deformation` to (GrabRequest,
ReleaseRequest, CutRequest).

Systems:
  simulation stage, ORDER_KINEMATICS (`cutting_tools`): reads Widget, Picked, Dragged and Scroll
      events and drives the chosen instrument. Within one frame the tool choice is applied first, then
      touches and drags, then pull / push / release. The instruments take over mouse drags from the
      deformation system (its own drag-to-pull is switched off at build time).
      Forceps: a touch (Picked: a click, or a scripted `pick` event) or the start of a drag on a layer
      grabs that layer's element nearest to the touched point. The tip then follows the hand at most
      `forceps.speed` mm/s, one GrabRequest per fixed step, so a fast hand move becomes a sequence of
      small ChainMail cascades. Targets come from drags (the point where the cursor ray meets the plane
      through the grab point facing the camera, see chainsim.components.view_events.Dragged), from the scripted widget
      events `pull` = "x, y, z" (world mm) and `pull_by` = "dx, dy, dz", from `push` = depth mm (along
      the layer's normal into the tissue; the Push button gives 2 mm) and from the scroll wheel in a
      frozen view (1 mm a notch). The end of a drag, `release`, or a change of tool opens the forceps.
      Scissors: the first touch picks the layer to cut; each later touch (or drag point) at least
      `scissors.min_step` mm further extends the path, and the segment from the previous point is sent
      as a CutRequest for that layer only, so cutting the top layer leaves the one beneath intact. The
      blade's depth direction is the view direction for mouse cuts and the layer's normal for scripted
      touches; drag points are carried along the line of sight onto the layer being cut. The stroke ends
      with the drag, `release`, or a change of tool.
  procedure stage, ORDER_PROCEDURE (`cutting_steps`): tool choice side effects (the frozen controller
      view jumps to the best view for the tool, 4.5.2; the mouse-driven viewer keeps its own), the
      `wireframe` and `reset`
      widgets, tool drawing (tip marker, shaft and blade lines, the current cut path; an idle
      instrument sits on the tissue point under the cursor, read from MouseMove), the pack's
      [[steps]] (pull, cut, open: each done when what it asks for has happened, in any order, 4.5.2)
      and HUD text.
  procedure stage, ORDER_ASSESSMENT (`cutting_assessment`): chainsim.game.app.headless.Assessment values.

Writes: Forceps / Scissors runtime fields, the tools' Transform / Marker / PolyLine, CuttingState
(resource), HudState, Assessment, viewport cameras (ViewState), the layers' [materials] `wireframe` in
this run's copy of the pack, DeformationState.drag_type (None).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import esper
import numpy as np

from chainsim.components.core import Marker, MeshRef, Name, PolyLine, Transform
from chainsim.components.deform_events import CutRequest, Deformed, GrabRequest, ReleaseRequest
from chainsim.components.deformable import Deformable
from chainsim.components.hud import HudState
from chainsim.components.input_events import MouseMove, Scroll, Widget
from chainsim.components.resources import Assessment, EntityIndex, PackResource
from chainsim.components.tools import Forceps, Scissors
from chainsim.components.view_events import Dragged, Picked
from chainsim.engine.errors import UserError
from chainsim.systems.deformation import DeformationState
from chainsim.systems.picking import entity_surface, pick, ray_mesh
from chainsim.systems.stages import ORDER_ASSESSMENT, ORDER_KINEMATICS, ORDER_PROCEDURE
from chainsim.systems.ui.viewports import OrbitCamera
from chainsim.systems.ui.widgets import WidgetState
from chainsim.systems.view import ViewState

TOOLS = ("forceps", "scissors")
STEP_IDS = ("pull", "cut", "open")
PUSH_BUTTON_MM = 2.0  # depth of one press of the Push button
SCROLL_MM = 1.0  # forceps travel along the normal per scroll notch
MOVED_MM = 0.01  # an element this far from rest counts as displaced
PULL_DONE_MM = 5.0  # 'pull' is done once a grip has carried tissue this far
CUT_DONE_MM = 20.0  # 'cut' is done after this much cut path that removed links
OPEN_DONE_MM = 10.0  # 'open' is done once a grip on a cut layer has carried it this far
#: best views for each tool (4.5.2), relative to the tissue's bounding sphere
VIEWS = {"forceps": dict(yaw=30.0, pitch=35.0, zoom=0.8), "scissors": dict(yaw=0.0, pitch=75.0, zoom=0.75)}


@dataclass(slots=True)
class ToolUse:
    tool: str
    layer: str
    start_s: float
    duration_s: float = 0.0


@dataclass(slots=True)
class CuttingState:
    """What the trainer is doing: the chosen tool, step progress, per-layer cut counts, tool uses."""

    tool: str = ""
    forceps: int = -1  # entity ids of the instruments
    scissors: int = -1
    layers: list = field(default_factory=list)  # deformable entity ids, top layer first
    top: int = -1
    names: dict = field(default_factory=dict)  # entity id -> name
    step_ids: list = field(default_factory=list)
    steps_done: list = field(default_factory=list)  # in the order they were done
    links_cut: dict = field(default_factory=dict)  # layer name -> links cut since the last reset
    cut_length: float = 0.0  # mm since the last reset
    wireframe: bool = False
    resets: int = 0
    uses: list = field(default_factory=list)  # ToolUse, in order
    open_use: ToolUse | None = None
    path_entity: int = -1  # runtime entity drawing the current cut path
    pending_view: str = ""  # tool whose best view is still to be applied
    drag_origin: tuple | None = None  # (tip, grab point) at the start of a forceps drag
    hover: np.ndarray | None = None  # world point of the tissue under the cursor (the idle tool sits there)
    # readers (made at build time so no event is missed)
    widgets: object = None
    picks: object = None
    drags: object = None
    scrolls: object = None
    moves: object = None
    deformed: object = None
    tool_widgets: object = None
    # cached assessment per layer: entity -> (version, alive count, values)
    cache: dict = field(default_factory=dict)


# -- geometry helpers ------------------------------------------------------------------------------


def _matrix(ent: int) -> np.ndarray:
    tr = esper.try_component(ent, Transform)
    return tr.matrix() if tr is not None else np.eye(4)


def world_positions(ent: int, d: Deformable) -> np.ndarray:
    m = _matrix(ent)
    return np.asarray(d.pos, dtype=np.float64) @ m[:3, :3].T + m[:3, 3]


def nearest_element(ent: int, d: Deformable, point) -> tuple[int, float]:
    """(element id, distance in mm) of the element of `d` nearest to a world point."""
    w = world_positions(ent, d)
    d2 = np.sum((w - np.asarray(point, dtype=np.float64)) ** 2, axis=1)
    i = int(np.argmin(d2))
    return i, math.sqrt(float(d2[i]))


def element_normal(app, ent: int, d: Deformable, element: int) -> np.ndarray:
    """Unit world normal of a layer at an element: the area-weighted mean of its triangles' normals
    (the side the triangles wind counter-clockwise around, i.e. away from the layers beneath)."""
    pres: PackResource = app.resource(PackResource)
    tris = pres.pack.mesh(esper.component_for_entity(ent, MeshRef).mesh).triangles
    around = tris[np.any(tris == element, axis=1)]
    w = world_positions(ent, d)
    if len(around) == 0:
        return np.array([0.0, 0.0, 1.0])
    n = np.cross(w[around[:, 1]] - w[around[:, 0]], w[around[:, 2]] - w[around[:, 0]]).sum(axis=0)
    norm = float(np.linalg.norm(n))
    return n / norm if norm > 1e-12 else np.array([0.0, 0.0, 1.0])


def parse_point(value, where: str) -> np.ndarray:
    """A point from a widget value: "x, y, z" (commas or spaces) or a list of 3 numbers."""
    if isinstance(value, str):
        parts = value.replace(",", " ").split()
    elif isinstance(value, (list, tuple)):
        parts = list(value)
    else:
        raise UserError(f'{where}: expected "x, y, z" in millimetres, got {value!r}')
    try:
        p = np.array([float(c) for c in parts], dtype=np.float64)
    except (TypeError, ValueError):
        raise UserError(f'{where}: expected "x, y, z" in millimetres, got {value!r}') from None
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise UserError(f'{where}: expected three finite numbers "x, y, z" in millimetres, got {value!r}')
    return p


def link_stretch(d: Deformable) -> float:
    """Largest current / rest length over the live links of a body (1.0 when nothing is stretched)."""
    links = d.graph.links[d.alive]
    if len(links) == 0:
        return 1.0
    cur = np.linalg.norm(d.pos[links[:, 1]] - d.pos[links[:, 0]], axis=1)
    rest = np.linalg.norm(d.rest[links[:, 1]] - d.rest[links[:, 0]], axis=1)
    ok = rest > 1e-12
    return float(np.max(cur[ok] / rest[ok])) if np.any(ok) else 1.0


# -- the instruments -------------------------------------------------------------------------------


class ToolsSystem:
    """Simulation stage: turns the trainee's input into grab, release and cut requests."""

    def __init__(self, app, st: CuttingState):
        self.st = st

    def hud(self, app):

        return app.get_resource(HudState)

    def say(self, app, text: str) -> None:
        h = self.hud(app)
        if h is not None:
            h.message(text, 3.0)

    def body(self, ent: int):
        if ent is None or ent < 0 or not esper.entity_exists(ent):
            return None
        return esper.try_component(ent, Deformable)

    # forceps ---------------------------------------------------------------------------------
    def grab(self, app, ent: int, point) -> bool:
        st = self.st
        f = esper.component_for_entity(st.forceps, Forceps)
        d = self.body(ent)
        if d is None:
            self.say(app, "The forceps only hold tissue.")
            return False
        self.open_forceps(app)
        elem, dist = nearest_element(ent, d, point)
        if dist > f.reach:
            self.say(app, "Nothing to grip there.")
            return False
        if d.fixed_mask[elem]:
            self.say(app, "That edge is fixed: grip the tissue further in.")
            return False
        f.held_entity, f.held_element = int(ent), elem
        f.tip = world_positions(ent, d)[elem].copy()
        f.target = f.tip.copy()
        f.grip_start = f.tip.copy()
        f.moving = False
        f.uses += 1
        f.use_start = app.time.sim_time
        st.open_use = ToolUse("forceps", st.names.get(ent, str(ent)), app.time.sim_time)
        st.uses.append(st.open_use)
        return True

    def open_forceps(self, app) -> None:
        st = self.st
        f = esper.component_for_entity(st.forceps, Forceps)
        if f.held_entity < 0:
            return
        app.events.emit(ReleaseRequest(f.held_entity, np.array([f.held_element])))
        held = app.time.sim_time - f.use_start
        f.time_used += held
        if st.open_use is not None and st.open_use.tool == "forceps":
            st.open_use.duration_s = held
            st.open_use = None
        f.held_entity, f.held_element, f.moving = -1, -1, False

    def aim(self, f: Forceps, target) -> None:
        f.target = np.asarray(target, dtype=np.float64).copy()
        f.moving = bool(np.any(f.target != f.tip))

    def push(self, app, depth: float) -> None:
        f = esper.component_for_entity(self.st.forceps, Forceps)
        d = self.body(f.held_entity)
        if d is None:
            self.say(app, "Grip the tissue with the forceps first.")
            return
        n = element_normal(app, f.held_entity, d, f.held_element)
        self.aim(f, f.target - n * float(depth))

    def move_tip(self, app) -> None:
        f = esper.component_for_entity(self.st.forceps, Forceps)
        if f.held_entity < 0 or not f.moving:
            return
        step = f.speed * app.time.dt
        delta = f.target - f.tip
        dist = float(np.linalg.norm(delta))
        if dist <= step:
            f.tip = f.target.copy()
            f.moving = False
        else:
            f.tip = f.tip + delta * (step / dist)
        app.events.emit(
            GrabRequest(f.held_entity, np.array([f.held_element]), f.tip[None, :].copy(), frame="world", hold=True)
        )

    # scissors --------------------------------------------------------------------------------
    def touch(self, app, ent: int, point, normal=None) -> None:
        st = self.st
        s = esper.component_for_entity(st.scissors, Scissors)
        p = np.asarray(point, dtype=np.float64)
        if s.stroke_entity < 0:
            if self.body(ent) is None:
                self.say(app, "The scissors only cut tissue.")
                return
            s.stroke_entity = int(ent)
            s.stroke = p[None, :].copy()
            s.uses += 1
            s.use_start = app.time.sim_time
            st.open_use = ToolUse("scissors", st.names.get(ent, str(ent)), app.time.sim_time)
            st.uses.append(st.open_use)
            return
        last = s.stroke[-1]
        step = float(np.linalg.norm(p - last))
        if step < max(s.min_step, 1e-9):
            return
        if normal is None:
            d = self.body(s.stroke_entity)
            # a scripted touch has no view direction: cut through the layer along its normal there
            elem, _ = nearest_element(s.stroke_entity, d, 0.5 * (p + last))
            normal = element_normal(app, s.stroke_entity, d, elem)
        app.events.emit(
            CutRequest(
                s.stroke_entity,
                p0=last.copy(),
                p1=p.copy(),
                normal=np.asarray(normal, dtype=np.float64),
                depth=float(s.depth),
                frame="world",
            )
        )
        s.stroke = np.vstack([s.stroke, p[None, :]])
        s.path_length += step
        st.cut_length += step

    def lift_blade(self, app) -> None:
        st = self.st
        s = esper.component_for_entity(st.scissors, Scissors)
        if s.stroke_entity < 0:
            return
        used = app.time.sim_time - s.use_start
        s.time_used += used
        if st.open_use is not None and st.open_use.tool == "scissors":
            st.open_use.duration_s = used
            st.open_use = None
        s.stroke_entity = -1

    # events ----------------------------------------------------------------------------------
    def choose(self, app, tool: str) -> None:
        st = self.st
        self.open_forceps(app)
        self.lift_blade(app)
        st.tool = tool
        st.pending_view = tool

    def on_widget(self, app, ev: Widget) -> None:
        st = self.st
        name = ev.name
        if name in TOOLS:
            self.choose(app, name)
        elif name == "release":
            self.open_forceps(app)
            self.lift_blade(app)
        elif name in ("pull", "pull_by", "push"):
            f = esper.component_for_entity(st.forceps, Forceps)
            if name == "push":
                value = PUSH_BUTTON_MM if ev.value is None else ev.value
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                    raise UserError(f"widget 'push': value must be a depth in mm, got {ev.value!r}")
            else:
                value = parse_point(ev.value, f"widget '{name}'")
            if st.tool != "forceps" or f.held_entity < 0:
                self.say(app, "Choose the forceps and grip the tissue first.")
                return
            if name == "push":
                self.push(app, float(value))
            elif name == "pull":
                self.aim(f, value)
            else:
                self.aim(f, f.target + value)

    def on_pick(self, app, ev: Picked) -> None:
        if ev.button != "left":
            return
        if self.st.tool == "forceps":
            self.grab(app, ev.entity, ev.point)
        elif self.st.tool == "scissors":
            normal = None
            if ev.viewport:
                cam = _camera(app, ev.viewport)
                normal = cam.forward if cam is not None else None
            self.touch(app, ev.entity, ev.point, normal)
        else:
            self.say(app, "Choose a tool in the toolbox first.")

    def on_drag(self, app, ev: Dragged) -> None:
        st = self.st
        if ev.button != "left":
            return
        if st.tool == "forceps":
            f = esper.component_for_entity(st.forceps, Forceps)
            if ev.phase == "start":
                if self.grab(app, ev.entity, ev.grab_point):
                    st.drag_origin = (f.tip.copy(), np.asarray(ev.grab_point, dtype=np.float64))
                else:
                    st.drag_origin = None
            elif st.drag_origin is not None and f.held_entity >= 0:
                tip0, gp = st.drag_origin
                self.aim(f, tip0 + (np.asarray(ev.point, dtype=np.float64) - gp))
                if ev.phase == "end":
                    st.drag_origin = None
                    f.release_on_arrival = True
        elif st.tool == "scissors":
            cam = _camera(app, ev.viewport)
            normal = cam.forward if cam is not None else None
            if ev.phase == "start":
                self.lift_blade(app)
                self.touch(app, ev.entity, ev.grab_point, normal)
            else:
                s = esper.component_for_entity(st.scissors, Scissors)
                if s.stroke_entity >= 0 and cam is not None:
                    self.touch(app, ev.entity, self.on_layer(app, s, cam.eye, ev.point), normal)
                if ev.phase == "end":
                    self.lift_blade(app)

    def on_layer(self, app, s: Scissors, eye, point) -> np.ndarray:
        """Where the line of sight through a drag point meets the layer being cut (the drag point itself
        lies on a plane facing the camera, which leaves the tissue as the cursor moves away): on the
        layer's live surface, else on the plane through the path's last point along the layer."""

        eye = np.asarray(eye, dtype=np.float64)
        ray = np.asarray(point, dtype=np.float64) - eye
        ray /= max(float(np.linalg.norm(ray)), 1e-12)
        surf = entity_surface(app, s.stroke_entity)
        if surf is not None:
            verts, tris, ids = surf
            hit = ray_mesh(eye, ray, verts, tris[ids])
            if hit is not None:
                return eye + hit[1] * ray
        d = self.body(s.stroke_entity)
        last = s.stroke[-1]
        n = element_normal(app, s.stroke_entity, d, nearest_element(s.stroke_entity, d, last)[0])
        denom = float(ray @ n)
        if abs(denom) < 1e-9:
            return np.asarray(point, dtype=np.float64)
        return eye + float((last - eye) @ n) / denom * ray

    def on_scroll(self, app, ev: Scroll) -> None:

        vs = app.get_resource(ViewState)
        vp = vs.at(ev.x, ev.y) if vs is not None else None
        if vp is None or not vp.is_3d or vp.mouse_camera or self.st.tool != "forceps":
            return  # an orbit view zooms with the wheel instead
        f = esper.component_for_entity(self.st.forceps, Forceps)
        if f.held_entity >= 0:
            self.push(app, -SCROLL_MM * ev.dy)

    def __call__(self, app) -> None:
        st = self.st
        # Within one frame: the tool choice first, then touches and drags (the view system reports
        # them after the raw input events), then what the hand does with the tool.
        widgets = st.widgets.read()
        for ev in widgets:
            if ev.name in TOOLS:
                self.on_widget(app, ev)
        for ev in st.picks.read():
            self.on_pick(app, ev)
        for ev in st.drags.read():
            self.on_drag(app, ev)
        for ev in st.scrolls.read():
            self.on_scroll(app, ev)
        for ev in widgets:
            if ev.name not in TOOLS:
                self.on_widget(app, ev)
        self.move_tip(app)
        f = esper.component_for_entity(st.forceps, Forceps)
        if f.release_on_arrival and not f.moving:
            f.release_on_arrival = False
            self.open_forceps(app)


def _camera(app, viewport: str):

    vs = app.get_resource(ViewState)
    vp = vs.get(viewport) if vs is not None and viewport else None
    return vp.camera if vp is not None else None


# -- views, reset, drawing -------------------------------------------------------------------------


def tissue_bounds(st: CuttingState) -> tuple[np.ndarray, np.ndarray]:
    pts = np.vstack([world_positions(e, esper.component_for_entity(e, Deformable)) for e in st.layers])
    return pts.min(axis=0), pts.max(axis=0)


def apply_view(app, st: CuttingState, tool: str) -> None:
    """Jump the frozen (controller) views to the tool's best view of the tissue (thesis 4.5.2): an
    oblique view from the free edge for the forceps, so pulling up and back is a drag up the screen; a
    near top-down view for the scissors, so a drag across the screen runs across the tissue. The
    mouse-driven viewer keeps the trainee's own viewpoint; a layout without a frozen view has its orbit
    views moved instead."""

    vs = app.get_resource(ViewState)
    if vs is None or tool not in VIEWS:
        return
    lo, hi = tissue_bounds(st)
    centre = 0.5 * (lo + hi)
    radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1.0)
    v = VIEWS[tool]
    frozen = [vp for vp in vs.viewports if vp.is_3d and not vp.mouse_camera]
    for vp in frozen or vs.viewports:
        cam = vp.camera
        if vp.kind not in ("orbit", "fixed") or not isinstance(cam, OrbitCamera):
            continue
        cam.target = centre.copy()
        cam.yaw, cam.pitch = v["yaw"], v["pitch"]
        cam.distance = radius / math.sin(math.radians(cam.fov) / 2.0) * v["zoom"]
        cam.update_eye()


def reset_tissue(app, st: CuttingState) -> None:
    """Every layer back to its rest shape with all links restored; instruments open; steps restart."""
    for ent in st.layers:
        d = esper.component_for_entity(ent, Deformable)
        d.pos[:] = d.rest
        d.graph.alive[:] = True
        if d.alive is not d.graph.alive:
            d.alive[:] = True
        d.held = np.zeros(0, dtype=np.int64)
        d.mark_dirty(np.arange(d.n_elements))
        d.version += 1
    f = esper.component_for_entity(st.forceps, Forceps)
    s = esper.component_for_entity(st.scissors, Scissors)
    now = app.time.sim_time
    if f.held_entity >= 0:
        f.time_used += now - f.use_start
    if s.stroke_entity >= 0:
        s.time_used += now - s.use_start
    if st.open_use is not None:
        st.open_use.duration_s = now - st.open_use.start_s
        st.open_use = None
    f.held_entity, f.held_element, f.moving, f.release_on_arrival = -1, -1, False, False
    s.stroke_entity = -1
    s.stroke = np.zeros((0, 3))
    st.drag_origin = None
    st.cut_length = 0.0
    st.steps_done = []
    st.resets += 1
    st.cache.clear()


def draw_tools(st: CuttingState) -> None:
    """Place the instruments: the forceps tip marker with a shaft line, the scissors with an open V of
    blades pointing along the cut, and the current cut path."""
    f = esper.component_for_entity(st.forceps, Forceps)
    s = esper.component_for_entity(st.scissors, Scissors)
    lift = np.array([0.0, 0.0, 0.3])  # drawn just above the surface, not inside it
    ftr = esper.component_for_entity(st.forceps, Transform)
    if f.held_entity < 0 and st.hover is not None:
        ftr.position = st.hover + lift  # the open forceps hover where the cursor is
    elif f.uses:
        ftr.position = f.tip.copy()
    shaft = np.array([0.25, 0.45, 1.0])
    shaft /= np.linalg.norm(shaft)
    fm = esper.try_component(st.forceps, Marker)
    fl = esper.component_for_entity(st.forceps, PolyLine)
    show_f = st.tool == "forceps"
    if fm is not None:
        fm.visible = show_f
    fl.points = np.vstack([ftr.position, ftr.position + shaft * f.lift])
    fl.visible = show_f
    str_ = esper.component_for_entity(st.scissors, Transform)
    along = np.array([0.0, -1.0, 0.0])
    if s.stroke_entity < 0 and st.hover is not None:
        str_.position = st.hover + lift
    elif len(s.stroke):
        str_.position = s.stroke[-1] + lift
        if len(s.stroke) > 1:
            seg = s.stroke[-1] - s.stroke[-2]
            if np.linalg.norm(seg) > 1e-9:
                along = seg / np.linalg.norm(seg)
    side = np.cross(along, [0.0, 0.0, 1.0])
    side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-9 else np.array([1.0, 0.0, 0.0])
    p = np.asarray(str_.position, dtype=np.float64)
    sl = esper.component_for_entity(st.scissors, PolyLine)
    sl.points = np.vstack([p - along * s.blade + side * 0.3 * s.blade, p, p - along * s.blade - side * 0.3 * s.blade])
    show_s = st.tool == "scissors"
    sl.visible = show_s
    sm = esper.try_component(st.scissors, Marker)
    if sm is not None:
        sm.visible = show_s
    path = esper.component_for_entity(st.path_entity, PolyLine)
    cutting = s.stroke_entity >= 0 and len(s.stroke) > 1
    path.visible = cutting
    path.points = s.stroke + lift if cutting else np.zeros((0, 3))


def hover_point(app, st: CuttingState, ev: MouseMove) -> np.ndarray | None:
    """The tissue point under the cursor in a 3-D view (where the idle instrument is drawn, so the mouse
    acts as the instrument, 4.5.2), or None off the tissue."""

    vs = app.get_resource(ViewState)
    vp = vs.at(ev.x, ev.y) if vs is not None else None
    if vp is None or not vp.is_3d or vp.camera is None:
        return None
    hit = pick(app, *vp.camera.ray(ev.x + 0.5, ev.y + 0.5, vp.rect))
    if hit is None or hit.entity not in st.names:
        return None
    return np.asarray(hit.point, dtype=np.float64)


def set_wireframe(app, st: CuttingState, on: bool) -> None:
    """Draw the layers as their links (to see them stretch) or shaded.

    The renderer takes `wireframe` from the layer's [materials] table, so the switch rewrites that
    table in this run's own copy of the pack (each App loads its pack afresh; nothing on disk changes).
    """
    st.wireframe = bool(on)
    pack = app.resource(PackResource).pack
    mats = pack.manifest.setdefault("materials", {})
    for ent in st.layers:
        name = esper.component_for_entity(ent, MeshRef).material
        if name in mats:
            mats[name] = dict(mats[name], wireframe=st.wireframe)


# -- steps and HUD ---------------------------------------------------------------------------------


class StepsSystem:
    """Procedure stage: tool side effects, reset / wireframe widgets, drawing, steps, HUD."""

    def __init__(self, st: CuttingState):
        self.st = st

    def step_done(self, app, step_id: str) -> bool:
        st = self.st
        f = esper.component_for_entity(st.forceps, Forceps)
        carried = float(np.linalg.norm(f.tip - f.grip_start)) if f.held_entity >= 0 else 0.0
        if step_id == "pull":
            return carried >= PULL_DONE_MM
        if step_id == "cut":
            return st.cut_length >= CUT_DONE_MM and any(_dead(e) for e in st.layers)
        if step_id == "open":
            return f.held_entity >= 0 and _dead(f.held_entity) > 0 and carried >= OPEN_DONE_MM
        return False

    def __call__(self, app) -> None:

        st = self.st
        hud = app.get_resource(HudState)
        ws = app.get_resource(WidgetState)
        for ev in st.tool_widgets.read():
            if ev.name == "reset":
                reset_tissue(app, st)
                if hud is not None:
                    hud.message("Tissue reset.", 3.0)
            elif ev.name == "wireframe":
                on = ws.get("wireframe") if ws is not None else (not st.wireframe if ev.value is None else ev.value)
                set_wireframe(app, st, bool(on))
        s = esper.component_for_entity(st.scissors, Scissors)
        for ev in st.deformed.read():
            if ev.cut_count and ev.entity in st.names:  # only the scissors cut in this procedure
                s.links_cut += ev.cut_count
        if st.pending_view:
            apply_view(app, st, st.pending_view)
            st.pending_view = ""
        moves = st.moves.read()
        if moves:
            st.hover = hover_point(app, st, moves[-1])
        draw_tools(st)
        pres: PackResource = app.resource(PackResource)
        steps = pres.pack.section("steps")
        # the thesis lets the trainee pull, cut and pull again in any order (4.5.2): a step is done when
        # what it asks for has happened, and the HUD shows the first step not yet done
        for k, sid in enumerate(st.step_ids):
            if sid not in st.steps_done and self.step_done(app, sid):
                st.steps_done.append(sid)
                if hud is not None:
                    last = len(st.steps_done) == len(st.step_ids)
                    hud.message("Opening made: all steps done." if last else f"Done: {steps[k].get('title', sid)}", 4.0)
        todo = [k for k, sid in enumerate(st.step_ids) if sid not in st.steps_done]
        if hud is not None:
            if todo:
                spec = steps[todo[0]]
                hud.step_title, hud.step_instruction = spec.get("title", ""), spec.get("instruction", "")
            elif st.step_ids:
                hud.step_title = "Done"
                hud.step_instruction = "Pull, cut and open again, or press Reset to start over."
            hud.panel_text = panel_lines(app, st)


def _dead(ent: int) -> int:
    d = esper.component_for_entity(ent, Deformable)
    return int(len(d.alive) - np.count_nonzero(d.alive))


def panel_lines(app, st: CuttingState) -> list[str]:
    v = app.resource(_assessment_type()).values
    f = esper.component_for_entity(st.forceps, Forceps)
    tool = st.tool or "none - take the forceps or the scissors"
    if st.tool == "forceps" and f.held_entity >= 0:
        tool += f" (holding {st.names.get(f.held_entity, '?')})"
    lines = [f"Tool: {tool}"]
    if v:
        cut = ", ".join(v["layers_cut"]) or "none"
        lines += [
            f"Links cut: {v['links_cut']} (layers: {cut})",
            f"Cut path: {v['cut_length_mm']:.1f} mm",
            f"Largest stretch: {v['max_stretch_ratio']:.2f} x rest",
            f"Elements displaced: {v['elements_moved']}",
        ]
    return lines


def _assessment_type():

    return Assessment


# -- assessment ------------------------------------------------------------------------------------


def layer_values(ent: int, d: Deformable) -> dict:
    disp = np.linalg.norm(np.asarray(d.pos, dtype=np.float64) - d.rest, axis=1)
    return {
        "links_cut": int(len(d.alive) - np.count_nonzero(d.alive)),
        "max_stretch_ratio": link_stretch(d),
        "elements_moved": int(np.count_nonzero(disp > MOVED_MM)),
        "max_displacement_mm": float(disp.max()) if len(disp) else 0.0,
    }


class AssessmentSystem:
    """Procedure stage, after the steps: the summary's assessment values (recomputed only for layers
    that changed since the last frame)."""

    def __init__(self, st: CuttingState):
        self.st = st

    def __call__(self, app) -> None:
        st = self.st
        per = {}
        for ent in st.layers:
            d = esper.component_for_entity(ent, Deformable)
            key = (d.version, int(np.count_nonzero(d.alive)))
            hit = st.cache.get(ent)
            if hit is None or hit[0] != key:
                hit = (key, layer_values(ent, d))
                st.cache[ent] = hit
            per[st.names[ent]] = hit[1]
        f = esper.component_for_entity(st.forceps, Forceps)
        s = esper.component_for_entity(st.scissors, Scissors)
        now = app.time.sim_time
        f_time = f.time_used + (now - f.use_start if f.held_entity >= 0 else 0.0)
        s_time = s.time_used + (now - s.use_start if s.stroke_entity >= 0 else 0.0)
        uses = []
        for u in st.uses:
            dur = (now - u.start_s) if u is st.open_use else u.duration_s
            uses.append({"tool": u.tool, "layer": u.layer, "start_s": round(u.start_s, 6), "duration_s": round(dur, 6)})
        values = {
            "tool": st.tool,
            "step": next((sid for sid in st.step_ids if sid not in st.steps_done), "done"),
            "steps_done": list(st.steps_done),
            "links_cut": sum(p["links_cut"] for p in per.values()),
            "links_cut_by_layer": {k: p["links_cut"] for k, p in per.items()},
            "layers_cut": [k for k, p in per.items() if p["links_cut"]],
            "top_layer": st.names[st.top],
            "cut_length_mm": st.cut_length,
            "max_stretch_ratio": max(p["max_stretch_ratio"] for p in per.values()),
            "max_stretch_by_layer": {k: p["max_stretch_ratio"] for k, p in per.items()},
            "elements_moved": sum(p["elements_moved"] for p in per.values()),
            "elements_moved_by_layer": {k: p["elements_moved"] for k, p in per.items()},
            "max_displacement_mm": max(p["max_displacement_mm"] for p in per.values()),
            "forceps_uses": f.uses,
            "scissors_uses": s.uses,
            "forceps_time_s": f_time,
            "scissors_time_s": s_time,
            "tool_uses": uses,
            "resets": st.resets,
            "wireframe": st.wireframe,
        }

        ds = app.get_resource(DeformationState)
        if ds is not None and ds.errors:
            values["deformation_errors"] = list(ds.errors)
        app.resource(_assessment_type()).values = values


# -- plugin ----------------------------------------------------------------------------------------


def plugin(app) -> None:
    """Install the cutting trainer for a spawned pack (see the module docstring)."""

    pres: PackResource = app.resource(PackResource)
    pack = pres.pack
    index: EntityIndex = app.resource(EntityIndex)
    st = CuttingState()
    with app.active():
        for comp, key in ((Forceps, "forceps"), (Scissors, "scissors")):
            ents = sorted(e for e, _ in esper.get_component(comp))
            if len(ents) != 1:
                raise UserError(
                    f"pack '{pack.name}': the cutting procedure needs exactly one entity with a "
                    f"[{key}] table in scene '{pres.scene}', found {len(ents)}"
                )
            setattr(st, key, ents[0])
        layers = sorted(e for e, _ in esper.get_component(Deformable))
        if not layers:
            raise UserError(
                f"pack '{pack.name}': the cutting procedure needs at least one tissue layer (an entity "
                f"with a [deformable] table) in scene '{pres.scene}'"
            )
        # top layer first: the highest at rest (ties by entity id, so the order is reproducible)
        heights = {
            e: float(np.mean(world_positions(e, esper.component_for_entity(e, Deformable))[:, 2])) for e in layers
        }
        st.layers = sorted(layers, key=lambda e: (-heights[e], e))
        st.top = st.layers[0]
        st.names = {e: esper.component_for_entity(e, Name).value for e in st.layers}
        step_ids = [s["id"] for s in pack.section("steps")]
        unknown = [s for s in step_ids if s not in STEP_IDS]
        if unknown:
            raise UserError(
                f"pack '{pack.name}': step '{unknown[0]}' is not a cutting-trainer step; steps are "
                f"{', '.join(STEP_IDS)}"
            )
        st.step_ids = step_ids
        for ent, color in ((st.forceps, (0.3, 0.85, 0.95, 1.0)), (st.scissors, (0.95, 0.85, 0.25, 1.0))):
            esper.add_component(ent, PolyLine(np.zeros((0, 3)), color, False, "tools"))
        st.path_entity = esper.create_entity(
            Name("cut_path"), PolyLine(np.zeros((0, 3)), (1.0, 0.25, 0.2, 1.0), False, "tools")
        )
        index.by_name.setdefault("cut_path", st.path_entity)
        f = esper.component_for_entity(st.forceps, Forceps)
        f.tip = np.array(esper.component_for_entity(st.forceps, Transform).position, dtype=np.float64)
        f.target = f.tip.copy()
        f.grip_start = f.tip.copy()
    ev = app.events
    st.widgets = ev.reader(Widget)
    st.picks = ev.reader(Picked)
    st.drags = ev.reader(Dragged)
    st.scrolls = ev.reader(Scroll)
    st.moves = ev.reader(MouseMove)
    st.deformed = ev.reader(Deformed)
    st.tool_widgets = ev.reader(Widget)
    app.insert_resource(st)

    ds = app.get_resource(DeformationState)
    if ds is not None:
        # the instruments interpret mouse drags (grip at the forceps' speed, or cut), so the deformation
        # system's own drag-to-pull must not act on them as well
        ds.drag_type = None
    if not app.has_resource(Assessment):
        app.insert_resource(Assessment())

    hud = app.get_resource(HudState)
    if hud is not None:
        hud.panel_text = ["Tool: none - take the forceps or the scissors"]
    app.add_system("simulation", ToolsSystem(app, st), order=ORDER_KINEMATICS, name="cutting_tools")
    app.add_system("procedure", StepsSystem(st), order=ORDER_PROCEDURE, name="cutting_steps")
    app.add_system("procedure", AssessmentSystem(st), order=ORDER_ASSESSMENT, name="cutting_assessment")

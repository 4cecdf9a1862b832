"""The cutting trainer's instruments (thesis 4.5.2): forceps that grab, pull and push a layer, scissors that cut it.

Simulation stage, ORDER_KINEMATICS. Tissue is only ever changed through deformation requests."""

from __future__ import annotations

import math

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.hud import HudState
from chainsim.components.input_events import Scroll, Widget
from chainsim.components.view_events import Dragged, Picked
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.raycast import ray_mesh
from chainsim.systems.procedures.cutting.state import (
    TOOLS,
    CuttingState,
    ToolUse,
    element_normal,
    nearest_element,
    parse_point,
    world_positions,
)
from chainsim.systems.procedures.cutting.tools import Forceps, Scissors
from chainsim.systems.tissue.deformable import Deformable
from chainsim.systems.tissue.events import CutRequest, GrabRequest, ReleaseRequest
from chainsim.systems.view.cameras import ViewState
from chainsim.systems.view.picking import entity_surface

# -- the instruments -------------------------------------------------------------------------------


def widget_value(name: str, value):
    """The value of a `pull` ("x, y, z"), `pull_by` ("dx, dy, dz") or `push` (mm; None: the Push button,
    the forceps' push_step) widget event, or one UserError line; scripts are checked with it before a run
    starts (procedure.check_event)."""
    if name == "push":
        if value is None:
            return None
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise UserError(f"widget 'push': value must be a depth in mm, got {value!r}")
        return float(value)
    return parse_point(value, f"widget '{name}'")


class ToolsSystem:
    """Simulation stage: turns the trainee's input into grab, release and cut requests."""

    def __init__(self, app: App, st: CuttingState):
        self.st = st

    def hud(self, app: App):

        return app.get_resource(HudState)

    def say(self, app: App, text: str) -> None:
        h = self.hud(app)
        if h is not None:
            h.message(text, 3.0)

    def body(self, ent: int):
        if ent is None or ent < 0 or not esper.entity_exists(ent):
            return None
        return esper.try_component(ent, Deformable)

    # forceps ---------------------------------------------------------------------------------
    def grab(self, app: App, ent: int, point) -> bool:
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
        if d.body.fixed[elem]:
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

    def open_forceps(self, app: App) -> None:
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

    def push(self, app: App, depth: float) -> None:
        f = esper.component_for_entity(self.st.forceps, Forceps)
        d = self.body(f.held_entity)
        if d is None:
            self.say(app, "Grip the tissue with the forceps first.")
            return
        n = element_normal(app, f.held_entity, d, f.held_element)
        self.aim(f, f.target - n * float(depth))

    def move_tip(self, app: App) -> None:
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
    def touch(self, app: App, ent: int, point, normal=None) -> None:
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

    def lift_blade(self, app: App) -> None:
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
    def choose(self, app: App, tool: str) -> None:
        st = self.st
        self.open_forceps(app)
        self.lift_blade(app)
        st.tool = tool
        st.pending_view = tool

    def on_widget(self, app: App, ev: Widget) -> None:
        st = self.st
        name = ev.name
        if name in TOOLS:
            self.choose(app, name)
        elif name == "release":
            self.open_forceps(app)
            self.lift_blade(app)
        elif name in ("pull", "pull_by", "push"):
            f = esper.component_for_entity(st.forceps, Forceps)
            value = widget_value(name, ev.value)
            if st.tool != "forceps" or f.held_entity < 0:
                self.say(app, "Choose the forceps and grip the tissue first.")
                return
            if name == "push":
                self.push(app, f.push_step if value is None else value)
            elif name == "pull":
                self.aim(f, value)
            else:
                self.aim(f, f.target + value)

    def on_pick(self, app: App, ev: Picked) -> None:
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

    def on_drag(self, app: App, ev: Dragged) -> None:
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

    def on_layer(self, app: App, s: Scissors, eye, point) -> np.ndarray:
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

    def on_scroll(self, app: App, ev: Scroll) -> None:

        vs = app.get_resource(ViewState)
        vp = vs.at(ev.x, ev.y) if vs is not None else None
        if vp is None or not vp.is_3d or vp.mouse_camera or self.st.tool != "forceps":
            return  # an orbit view zooms with the wheel instead
        f = esper.component_for_entity(self.st.forceps, Forceps)
        if f.held_entity >= 0:
            self.push(app, -f.scroll_step * ev.dy)

    def __call__(self, app: App) -> None:
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


def _camera(app: App, viewport: str):

    vs = app.get_resource(ViewState)
    vp = vs.get(viewport) if vs is not None and viewport else None
    return vp.camera if vp is not None else None

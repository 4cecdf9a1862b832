"""The cutting trainer's steps, views and drawing (thesis 4.5.2): tool side effects, reset and wireframe, the
pack's [[steps]], the instruments' drawing and the HUD. Procedure stage, ORDER_PROCEDURE."""

from __future__ import annotations

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import Marker, PolyLine, Transform, Wireframe
from chainsim.components.hud import HudState
from chainsim.components.input_events import MouseMove
from chainsim.components.resources import Assessment, PackResource
from chainsim.systems.procedures.cutting.state import (
    CuttingState,
    world_positions,
)
from chainsim.systems.procedures.cutting.tools import Forceps, Scissors
from chainsim.systems.tissue.deformable import Deformable
from chainsim.systems.tissue.events import ResetRequest
from chainsim.systems.view.cameras import ViewState, frame_view
from chainsim.systems.view.picking import pick
from chainsim.systems.view.ui.viewports import OrbitCamera
from chainsim.systems.view.ui.widgets import WidgetState

TOOL_COMPONENTS = {"forceps": Forceps, "scissors": Scissors}

# -- views, reset, drawing -------------------------------------------------------------------------


def tissue_bounds(st: CuttingState) -> tuple[np.ndarray, np.ndarray]:
    pts = np.vstack([world_positions(e, esper.component_for_entity(e, Deformable)) for e in st.layers])
    return pts.min(axis=0), pts.max(axis=0)


def apply_view(app: App, st: CuttingState, tool: str) -> None:
    """Jump the frozen (controller) views to the tool's best view of the tissue (thesis 4.5.2): an
    oblique view from the free edge for the forceps, so pulling up and back is a drag up the screen; a
    near top-down view for the scissors, so a drag across the screen runs across the tissue. The view
    is framed on the layers (every corner of their box inside it). The mouse-driven viewer keeps the
    trainee's own viewpoint; a layout without a frozen view has its orbit views moved instead."""

    vs = app.get_resource(ViewState)
    if vs is None or tool not in TOOL_COMPONENTS:
        return
    lo, hi = tissue_bounds(st)
    if vs.scene_box is not None:  # the tissue as it is now, and the whole scene as it was (the brain too)
        lo, hi = np.minimum(lo, vs.scene_box[0]), np.maximum(hi, vs.scene_box[1])
    comp = esper.component_for_entity(getattr(st, tool), TOOL_COMPONENTS[tool])
    frozen = [vp for vp in vs.viewports if vp.is_3d and not vp.mouse_camera]
    for vp in frozen or vs.viewports:
        cam = vp.camera
        if vp.kind not in ("orbit", "fixed") or not isinstance(cam, OrbitCamera):
            continue
        cam.yaw, cam.pitch = comp.view_yaw, comp.view_pitch
        frame_view(vs, vp, lo, hi)


def reset_tissue(app: App, st: CuttingState) -> None:
    """Every layer back to its rest shape with all links restored; instruments open; steps restart."""
    for ent in st.layers:
        app.events.emit(ResetRequest(ent))  # served by the deformation system, which owns the tissue
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


def hover_point(app: App, st: CuttingState, ev: MouseMove) -> np.ndarray | None:
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


def set_wireframe(app: App, st: CuttingState, on: bool) -> None:
    """Draw the layers as their links (to see them stretch) or shaded: a Wireframe component the
    renderer reads; the pack's materials are never changed."""
    st.wireframe = bool(on)
    for ent in st.layers:
        if st.wireframe:
            esper.add_component(ent, Wireframe())
        elif esper.has_component(ent, Wireframe):
            esper.remove_component(ent, Wireframe)


# -- steps and HUD ---------------------------------------------------------------------------------


class StepsSystem:
    """Procedure stage: tool side effects, reset / wireframe widgets, drawing, steps, HUD."""

    def __init__(self, st: CuttingState):
        self.st = st

    def step_done(self, app: App, k: int) -> bool:
        """Whether step k's `done_on` events (or, for a step without them, its id's: state.LEGACY_DONE_ON)
        have happened: any one completes the step."""
        st = self.st
        f = esper.component_for_entity(st.forceps, Forceps)
        carried = float(np.linalg.norm(f.tip - f.grip_start)) if f.held_entity >= 0 else 0.0
        for kind, mm in st.step_events[k]:
            if kind == "carried" and carried >= mm:
                return True
            if kind == "cut" and st.cut_length >= mm and any(_dead(e) for e in st.layers):
                return True
            if kind == "opened" and f.held_entity >= 0 and _dead(f.held_entity) > 0 and carried >= mm:
                return True
        return False

    def __call__(self, app: App) -> None:

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
            if sid not in st.steps_done and self.step_done(app, k):
                st.steps_done.append(sid)
                if hud is not None:
                    last = len(st.steps_done) == len(st.step_ids)
                    hud.message("Opening made: all steps done." if last else f"Done: {steps[k].get('title', sid)}", 4.0)
        todo = [k for k, sid in enumerate(st.step_ids) if sid not in st.steps_done]
        if hud is not None:
            if todo:
                spec = steps[todo[0]]
                hud.step_title, hud.step_instruction = spec.get("title", ""), spec.get("instruction", "")
                hud.step_doc = spec.get("docs", "")
            elif st.step_ids:
                hud.step_title = "Done"
                hud.step_instruction = "Pull, cut and open again, or press Reset tissue (r) to start over."
            hud.panel_text = panel_lines(app, st)


def _dead(ent: int) -> int:
    alive = esper.component_for_entity(ent, Deformable).body.alive
    return int(len(alive) - np.count_nonzero(alive))


def panel_lines(app: App, st: CuttingState) -> list[str]:
    v = app.resource(Assessment).values
    f = esper.component_for_entity(st.forceps, Forceps)
    tool = st.tool or "none - take the forceps or the scissors"
    if st.tool == "forceps" and f.held_entity >= 0:
        tool += f" (holding {st.names.get(f.held_entity, '?')})"
    top = esper.component_for_entity(st.top, Deformable).body
    lines = [f"Tool: {tool}", f"Tissue model: {top.model_used} (m switches)"]
    if top.model_reason.startswith("auto"):  # which model the budget chose, and why
        lines.append(top.model_reason)
    if v:
        cut = ", ".join(v["layers_cut"]) or "none"
        lines += [
            f"Links cut: {v['links_cut']} (layers: {cut})",
            f"Cut path: {v['cut_length_mm']:.1f} mm",
            f"Largest stretch: {v['max_stretch_ratio']:.2f} x rest",
            f"Elements displaced: {v['elements_moved']}",
        ]
    return lines

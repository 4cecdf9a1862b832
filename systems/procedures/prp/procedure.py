"""The percutaneous rhizotomy procedure (thesis 3.2.3 task analysis, 3.3.4 interface, 3.3.6 feedback).

`plugin(app)` is what `pack.procedure = "prp"` installs: the anatomy resource, the needle kinematics
(chainsim.systems.needle), the swept collision test (chainsim.systems.collision), this step machine and the assessment
(chainsim.systems.procedures.prp.assessment) and the C-arm (chainsim.systems.procedures.prp.fluoro).

Stage: procedure (ORDER_PROCEDURE). Reads: Picked, Widget, NeedleAction, NeedleReset,
RotationRefused, InsertRefused and NeedleHit events; WidgetState (aid toggles). Writes:
ProcedureState (on a runtime entity "procedure"), the landmark marker and landmark-plane entities,
HudState (step title and instruction, messages, the red/green lights).

Steps (the pack's [[steps]], in this order): reading -> landmark1 -> landmark2 -> landmark3 ->
orient_horizontal -> orient_vertical -> insert -> review. Landmarks are placed by clicks (Picked) on
the entity "skin", one per click in step order; clicks on anything else are ignored with a message.
Landmark 1 decides the side (the half of the head it lies in, from the named anatomy) and the needle jumps
to it (3.3.4: the simulator places the needle so the trainee can concentrate on orienting and
inserting). Steps only move forward, following what the trainee does (a rotation about the vertical
axis means orient_horizontal, and so on); Next cannot skip a landmark that is not placed (the HUD
says which click is missing). Time is booked per fixed simulation step to the step that is current,
so a session gives the same times whatever the frame rate it ran at.

Attempts: an attempt has its own clock, path length, contacts, redirections and step times. Saving
closes it (its clock stops); the next action - a reset, a turn, an insertion, a landmark - begins the
next attempt from zero, keeping the landmarks unless shift+Reset clears them.

Aiming aid: every frame the HUD gets the entry side's foramen ovale centre and the tip's distance to
it, which the needle-tip view draws with a crosshair (chainsim.game.gl.panelview.aim).
"""

from __future__ import annotations

import esper
import numpy as np

from chainsim.components.core import Label, Marker, MeshRef, Name, Transform
from chainsim.components.input_events import Widget
from chainsim.components.needle import Needle, NeedleState
from chainsim.components.procedure import LANDMARK_COUNT, ProcedureState, PrpAnatomy, anatomy_from_pack
from chainsim.components.resources import EntityIndex, PackResource
from chainsim.components.view_events import Picked, WidgetRefused
from chainsim.engine import quaternion as Q
from chainsim.engine.errors import UserError
from chainsim.systems import collision
from chainsim.systems import needle as needle_sys
from chainsim.systems.collision import NeedleHit
from chainsim.systems.needle import InsertRefused, NeedleAction, NeedleReset, RotationRefused
from chainsim.systems.procedures.prp import assessment, fluoro
from chainsim.systems.procedures.prp.handles import PrpHandles, hud
from chainsim.systems.stages import ORDER_PROCEDURE
from chainsim.systems.ui.widgets import WidgetState

STEP_IDS = (
    "reading",
    "landmark1",
    "landmark2",
    "landmark3",
    "orient_horizontal",
    "orient_vertical",
    "insert",
    "review",
)
AIDS = ("skin_transparent", "reference_planes", "landmark_planes", "tip_view", "collision_signals")
LIGHTS = ("skull", "target")
SKIN = "skin"
#: landmark k (1-based) shows the plane the thesis associates with it: axial through 1, sagittal
#: through 2, coronal through 3 (3.3.4: the coronal and sagittal planes meet over the foramen)
LANDMARK_PLANE_NORMALS = ((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))


def widget_state(app):
    return app.get_resource(WidgetState)


class ProcedureSystem:
    def __init__(self, app):
        self.picks = app.events.reader(Picked)
        self.widgets = app.events.reader(Widget)
        self.actions = app.events.reader(NeedleAction)
        self.resets = app.events.reader(NeedleReset)
        self.refused = app.events.reader(RotationRefused)
        self.widget_refused = app.events.reader(WidgetRefused)
        self.insert_refused = app.events.reader(InsertRefused)
        self.hits = app.events.reader(NeedleHit)
        pres: PackResource = app.resource(PackResource)
        self.steps = {s["id"]: s for s in pres.pack.section("steps")}
        self.layout_widgets = {w["name"]: w for w in pres.layout.get("widgets", [])}
        self.last_tick = app.time.tick
        self.lights = {name: "off" for name in LIGHTS}
        # the attached view that rides on the needle shows the aiming aid
        needle_name = next(
            (n for n, e in app.resource(EntityIndex).by_name.items() if e == app.resource(PrpHandles).needle), ""
        )
        self.tip_view = next(
            (v["name"] for v in pres.layout.get("viewports", []) if v.get("attach") == needle_name), ""
        )

    # -- helpers --------------------------------------------------------------------------------
    def state(self, app) -> ProcedureState:
        return esper.component_for_entity(app.resource(PrpHandles).procedure, ProcedureState)

    def needle(self, app):
        ent = app.resource(PrpHandles).needle
        return ent, esper.component_for_entity(ent, Needle), esper.component_for_entity(ent, NeedleState)

    def goto(self, app, ps: ProcedureState, step_id: str) -> None:
        """Move forward to `step_id` (never back, except through `restart`)."""
        if step_id not in ps.step_ids:
            return
        k = ps.step_ids.index(step_id)
        if k <= ps.step:
            return
        ps.step = k
        self.show_step(app, ps)

    def restart(self, app, ps: ProcedureState, step_id: str) -> None:
        if step_id in ps.step_ids:
            ps.step = ps.step_ids.index(step_id)
            self.show_step(app, ps)

    def show_step(self, app, ps: ProcedureState) -> None:
        spec = self.steps.get(ps.step_id, {})
        h = hud(app)
        h.step_title = spec.get("title", ps.step_id)
        h.step_instruction = spec.get("instruction", "")
        h.step_doc = spec.get("docs", "") or h.step_doc
        h.doc_name = h.step_doc or h.doc_name
        # the reading step opens its page in the app (thesis 3.4); later steps keep it a Help press away
        if ps.step_id == "reading":
            h.open_doc()
        else:
            h.close_doc()

    # -- landmarks ------------------------------------------------------------------------------
    def begin_attempt(self, app, ps: ProcedureState) -> None:
        """After a saved attempt, the first action starts a new one with its own clock and counts."""
        if not ps.closed:
            ps.touched = True
            return
        _ent, _needle, st = self.needle(app)
        needle_sys.new_attempt(st)
        ps.closed = False
        ps.touched = True
        ps.attempt += 1
        ps.elapsed = 0.0
        ps.step_times = {}
        ps.aids = dict(ps.aids_now)
        ps.finished = False
        ps.target = "none"
        ps.needle_dist = float("nan")
        ps.hit_point = np.full(3, np.nan)
        self.lights["skull"] = self.lights["target"] = "off"
        hud(app).panel_text = []
        hud(app).message(f"Attempt {ps.attempt} begins: its time, path and contacts count from zero.")

    def place_landmark(self, app, ps: ProcedureState, point) -> None:
        h = hud(app)
        if ps.placed >= LANDMARK_COUNT:
            h.message("All three landmarks are placed; Reset with shift (or reset 'all') to place them again.")
            return
        k = ps.placed
        p = np.asarray(point, dtype=np.float64)
        ps.landmarks[k] = p
        ps.placed += 1
        self.show_landmark(app, k, p)
        if k == 0:
            ps.side = _side(app, p)
            ent, needle, st = self.needle(app)
            needle_sys.place(app, ent, needle, st, p)
            h.message(f"Landmark 1 placed on the {ps.side} cheek; the needle is at the entry point.")
        else:
            h.message(f"Landmark {k + 1} placed.")
        self.goto(app, ps, f"landmark{k + 2}" if k + 1 < LANDMARK_COUNT else "orient_horizontal")

    def show_landmark(self, app, k: int, p) -> None:
        handles: PrpHandles = app.resource(PrpHandles)
        if k < len(handles.markers) and handles.markers[k] is not None:
            tr = esper.try_component(handles.markers[k], Transform)
            if tr is not None:
                tr.position = np.asarray(p, dtype=np.float64).copy()
            mk = esper.try_component(handles.markers[k], Marker)
            if mk is not None:
                mk.visible = True
            lb = esper.try_component(handles.markers[k], Label)
            if lb is not None:
                lb.text = handles.labels[k]
        if k < len(handles.planes) and handles.planes[k] is not None:
            tr = esper.try_component(handles.planes[k], Transform)
            if tr is not None:
                tr.position = np.asarray(p, dtype=np.float64).copy()
                tr.rotation = Q.look_rotation(LANDMARK_PLANE_NORMALS[k], (0.0, 1.0, 0.0) if k == 0 else (0.0, 0.0, 1.0))

    def clear_landmarks(self, app, ps: ProcedureState) -> None:
        ps.landmarks[:] = np.nan
        ps.placed = 0
        ps.side = ""
        handles: PrpHandles = app.resource(PrpHandles)
        _hide_markers(handles.markers)
        for ent in handles.planes:
            ref = esper.try_component(ent, MeshRef) if ent is not None else None
            if ref is not None:
                ref.visible = False

    # -- the system -----------------------------------------------------------------------------
    def __call__(self, app) -> None:
        ps = self.state(app)
        h = hud(app)
        self.lights = ps_lights(ps)
        ws = widget_state(app)
        # aids: an aid counts for the attempt if it was on at any time (the trainee had it)
        for name in AIDS:
            on = (
                bool(ws.values.get(name, False))
                if ws is not None and name in ws.values
                else bool(self.layout_widgets.get(name, {}).get("value", False))
            )
            ps.aids[name] = ps.aids.get(name, False) or on
            ps.aids_now[name] = on
        if self.picks is not None:
            for ev in self.picks.read():
                if ev.entity_name != SKIN:
                    h.message(f"Landmarks go on the skin of the face; that click was on '{ev.entity_name}'.")
                    continue
                if ps.step_id == "reading":
                    self.goto(app, ps, "landmark1")
                if ps.placed < LANDMARK_COUNT:
                    self.begin_attempt(app, ps)
                self.place_landmark(app, ps, ev.point)
        for ev in self.widgets.read():
            if ev.name == "next":
                self.next_step(app, ps)
        for ev in self.resets.read():
            self.begin_attempt(app, ps)
            h.panel_text = []
            self.lights["skull"] = self.lights["target"] = "off"
            ps.target = "none"
            ps.needle_dist = float("nan")
            ps.hit_point = np.full(3, np.nan)
            ps.finished = False
            if ev.all:
                self.clear_landmarks(app, ps)
                ps.aids = dict(ps.aids_now)  # a new attempt: its own aids, times and counts
                ps.step_times = {}
                ps.elapsed = 0.0
                ps.finished = False
                self.restart(app, ps, "landmark1")
                h.message("Landmarks cleared: place landmark 1 again.")
            else:
                self.restart(app, ps, "orient_horizontal" if ps.placed else "landmark1")
                h.message("Needle reset to landmark 1, dials at zero, rotation unlocked.")
        for ev in self.widget_refused.read():
            if ev.name in ("rotate_horizontal", "rotate_vertical"):
                h.message(LOCKED)
        for ev in self.refused.read():
            if ev.reason == "locked":
                h.message(LOCKED)
            else:
                h.message("Place landmark 1 on the cheek first: the needle starts there.")
        for ev in self.insert_refused.read():
            if ev.reason == "not_placed":
                h.message("Place landmark 1 on the cheek first: the needle starts there.")
            elif ev.reason == "in_target":
                h.message("The needle is in the foramen ovale; press Reset to try again.")
            elif ev.reason == "max_depth":
                h.message("That is as deep as the needle goes.")
        for ev in self.actions.read():
            if ev.kind == "withdrawn":
                h.message("The needle is back at the skin: the dials are free; turn them to redirect.")
                continue
            self.begin_attempt(app, ps)
            if ev.kind == "rotate_horizontal":
                self.goto(app, ps, "orient_horizontal")
            elif ev.kind == "rotate_vertical":
                self.goto(app, ps, "orient_vertical")
            elif ev.kind in ("insert", "withdraw") and ev.value > 0:
                self.goto(app, ps, "insert")
        for ev in self.hits.read():
            ps.target = ev.object
            ps.needle_dist = float(ev.distance_to_target_mm)
            ps.hit_point = np.asarray(ev.point, dtype=np.float64)
            if ev.object.startswith("foramen_ovale_") and ev.object.endswith(ps.side or "?"):
                self.lights["target"], self.lights["skull"] = "green", "off"
                ps.finished = True
                h.message("Well done: the needle has entered the foramen ovale.")
                self.goto(app, ps, "review")
            else:
                self.lights["skull"], self.lights["target"] = "red", "off"
                what = (
                    "the skull"
                    if ev.object == "skull"
                    else ("the mandible" if ev.object == "mandible" else ev.object.replace("_", " "))
                )
                radius = _radius(app, ps)
                h.message(
                    f"The needle hit {what} with its tip {ev.distance_to_target_mm:.1f} mm from the centre of the "
                    f"foramen ovale (needle error {ev.distance_to_target_mm - radius:.1f} mm: that distance minus "
                    f"the opening's radius, {radius:.1f} mm); it springs back."
                )
        ps.lights = dict(self.lights)
        show = ps.aids_now.get("collision_signals", True)
        for name in LIGHTS:
            h.set_light(name, self.lights[name] if show else "off")
        self.update_planes(app, ps)
        self.update_aim(app, ps)
        # time per step, in fixed simulation steps (never the frame's length, which depends on the
        # machine); the clock stops once the needle is in the foramen or the attempt is saved
        ticks, self.last_tick = app.time.tick - self.last_tick, app.time.tick
        if not ps.finished and not ps.closed and ticks > 0:
            sid = ps.step_id
            ps.step_times[sid] = ps.step_times.get(sid, 0.0) + ticks * app.time.dt
            ps.elapsed += ticks * app.time.dt

    def next_step(self, app, ps: ProcedureState) -> None:
        """Next moves on one step, except past a landmark that is not placed yet."""
        sid = ps.step_id
        if sid.startswith("landmark") and ps.placed < int(sid[-1]):
            k = ps.placed + 1
            where = self.steps.get(f"landmark{k}", {}).get("instruction", "")
            hud(app).message(f"Landmark {k} is not placed yet: the steps go in order. {where}")
            return
        if ps.step + 1 < len(ps.step_ids):
            self.goto(app, ps, ps.step_ids[ps.step + 1])

    def update_aim(self, app, ps: ProcedureState) -> None:
        """The tip view's aiming aid: the entry side's foramen ovale and the tip's distance to it."""

        h = hud(app)
        h.aim_view = self.tip_view
        _ent, _needle, st = self.needle(app)
        if not st.placed:
            h.aim_target, h.aim_note = None, "place landmark 1 first"
            return
        centre = app.resource(PrpAnatomy).sides[ps.side or "left"].foramen_centre
        h.aim_target = tuple(float(c) for c in centre)
        h.aim_note = f"{float(np.linalg.norm(st.tip() - centre)):.1f} mm"

    def update_planes(self, app, ps: ProcedureState) -> None:
        on = ps.aids_now.get("landmark_planes", False)
        handles: PrpHandles = app.resource(PrpHandles)
        for k, ent in enumerate(handles.planes):
            ref = esper.try_component(ent, MeshRef) if ent is not None else None
            if ref is not None:
                ref.visible = bool(on and k < ps.placed)


LOCKED = (
    "The dials are locked while the needle is in: withdraw it to the skin (o, or the depth slider to 0) "
    "to turn it again, or press Reset."
)


def _radius(app, ps: ProcedureState) -> float:

    return float(app.resource(PrpAnatomy).sides[ps.side or "left"].foramen_radius)


def ps_lights(ps: ProcedureState) -> dict:
    out = {name: "off" for name in LIGHTS}
    out.update(ps.lights)
    return out


def _side(app, p) -> str:

    return app.resource(PrpAnatomy).side_of(p)


def _hide_markers(markers: list) -> None:
    """Unplaced landmarks are not drawn: marker hidden, label emptied (labels have no visible flag)."""
    for ent in markers:
        if ent is None:
            continue
        mk = esper.try_component(ent, Marker)
        if mk is not None:
            mk.visible = False
        lb = esper.try_component(ent, Label)
        if lb is not None:
            lb.text = ""


def plugin(app) -> None:

    pres: PackResource = app.resource(PackResource)
    pack = pres.pack
    app.insert_resource(anatomy_from_pack(pack))
    index: EntityIndex = app.resource(EntityIndex)
    with app.active():
        needles = [ent for ent, _ in esper.get_component(Needle)]
        if len(needles) != 1:
            raise UserError(
                f"pack '{pack.name}': the rhizotomy procedure needs exactly one entity with a [needle] table, "
                f"found {len(needles)}"
            )
        if index.get(SKIN) is None:
            raise UserError(
                f"pack '{pack.name}': the rhizotomy procedure needs an entity named '{SKIN}' "
                "(landmarks are clicked on it)"
            )
        step_ids = [s["id"] for s in pack.section("steps")]
        unknown = [s for s in step_ids if s not in STEP_IDS]
        if unknown:
            raise UserError(
                f"pack '{pack.name}': step '{unknown[0]}' is not a rhizotomy step; steps are {', '.join(STEP_IDS)}"
            )
        ps = ProcedureState(step_ids=step_ids or list(STEP_IDS))
        proc = esper.create_entity(Name("procedure"), ps)
        index.by_name["procedure"] = proc
        markers = [index.get(f"landmark{k}") for k in range(1, LANDMARK_COUNT + 1)]
        planes = [index.get(f"landmark_plane{k}") for k in range(1, LANDMARK_COUNT + 1)]
        labels = []
        for ent in markers:
            lb = esper.try_component(ent, Label) if ent is not None else None
            labels.append(lb.text if lb is not None else "")
        _hide_markers(markers)
        for ent in planes:
            ref = esper.try_component(ent, MeshRef) if ent is not None else None
            if ref is not None:
                ref.visible = False
    app.insert_resource(PrpHandles(needles[0], proc, markers, planes, labels))
    needle_sys.plugin(app)
    collision.plugin(app)
    system = ProcedureSystem(app)
    with app.active():
        system.show_step(app, ps)
    app.add_system("procedure", system, order=ORDER_PROCEDURE, name="prp_procedure")
    fluoro.plugin(app)
    assessment.plugin(app)

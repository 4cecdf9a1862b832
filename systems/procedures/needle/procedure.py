"""The generic needle procedure (thesis 3.2.3 task analysis, 3.3.4 interface, 3.3.6 feedback).

`plugin(app)` is what `pack.procedure = "needle"` installs: the NeedleScene resource read from the
pack's [needle_procedure], [roles], [[landmarks]] (chainsim.systems.procedures.needle.manifest), the needle
kinematics (kinematics.py), the swept collision test (collision.py), this
step machine, the assessment (.assessment) and the C-arm (.fluoro). Nothing here knows a procedure:
every name, message, light and step comes from the pack (docs/needle-procedures.md).

Stage: procedure (ORDER_PROCEDURE). Reads: Picked, Widget, NeedleAction, NeedleReset,
RotationRefused, InsertRefused and NeedleHit events; WidgetState (aid toggles). Writes:
ProcedureState (on a runtime entity "procedure"), the landmark marker and landmark-plane entities,
HudState (step title and instruction, messages, lights).

Steps (the pack's [[steps]], in order) move forward only: an event a step names in `done_on` moves
on to the step after it (never back), and Next moves on one step, except out of a step whose
`landmark` is not placed yet. Landmarks are placed by clicks (Picked) on an entity of their `on` role,
one per click in [[landmarks]] order; other clicks are ignored with a message. The `side_from`
landmark decides the side (the side whose target centre is nearest) and the `entry` landmark places
the needle (3.3.4: the simulator places the needle so the trainee can concentrate on orienting and
inserting). Reaching the target stops the attempt's clock. Time is booked per fixed simulation step
to the step that is current, so a session gives the same times whatever the frame rate it ran at.

Attempts: an attempt has its own clock, path length, contacts, redirections and step times. Saving
closes it (its clock stops); the next action - a reset, a turn, an insertion, a landmark - begins the
next attempt from zero, keeping the landmarks unless shift+Reset clears them.

Aiming aid: every frame the HUD gets the entry side's target centre and the tip's distance to it,
which the needle-tip view draws with a crosshair (chainsim.game.render.panelview.aim); in fluoroscopy-first
mode (.fluoro.fluoro_first) it gets neither, only a note, and the trainee guides by the X-ray.
"""

from __future__ import annotations

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import Label, Marker, MeshRef, Name, Transform
from chainsim.components.input_events import Widget
from chainsim.components.resources import EntityIndex, PackResource, RunInfo
from chainsim.components.stages import ORDER_PROCEDURE
from chainsim.components.view_events import Picked
from chainsim.systems.engine import quaternion as Q
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures.needle import assessment, collision, fluoro, tissue
from chainsim.systems.procedures.needle import kinematics as needle_sys
from chainsim.systems.procedures.needle.collision import NeedleHit
from chainsim.systems.procedures.needle.components import Needle, NeedleState
from chainsim.systems.procedures.needle.handles import Feedback, NeedleHandles, hud
from chainsim.systems.procedures.needle.kinematics import (
    ROTATION_WIDGETS,
    InsertRefused,
    NeedleAction,
    NeedleReset,
    RotationRefused,
)
from chainsim.systems.procedures.needle.manifest import NeedleScene, ProcedureState, scene_from_pack
from chainsim.systems.view.ui.widgets import WidgetState

#: what is said when the pack's [[feedback]] says nothing for an event
DEFAULTS = {
    "click_elsewhere": "That click was on '{entity}', not where landmark {n} goes.",
    "landmarks_full": "All landmarks are placed; Reset with shift (or reset 'all') to place them again.",
    "landmark_missing": "Landmark {n} is not placed yet: the steps go in order. {instruction}",
    "landmark": "Landmark {n} placed.",
    "withdrawn": "The needle is back at the skin: the dials are free; turn them to redirect.",
    "turn_held": "The needle is on its way back to the skin: the turn is made when it gets there.",
    "turns_dropped": "The needle went in again before it reached the skin: {n} turns asked for on the way "
    "back were not made.",
    "refused:locked": "The dials are locked while the needle is in: withdraw it to the skin, or press Reset.",
    "refused:not_placed": "Place landmark {n} first: the needle starts there.",
    "refused:in_target": "The needle is in the target; press Reset to try again.",
    "refused:max_depth": "That is as deep as the needle goes.",
    "reset": "Needle reset to the entry point, dials at zero, rotation unlocked.",
    "reset_all": "Landmarks cleared: place landmark 1 again.",
    "attempt": "Attempt {attempt} begins: its time, path and contacts count from zero.",
    "contact:target": "The needle reached {what}.",
    "contact": "The needle touched {what}, its tip {dist_mm:.1f} mm from the target centre.",
    "contact_again": "Still on {what} at the same place: one contact until you withdraw {withdraw_mm:g} mm, "
    "turn the needle or meet it elsewhere.",
}


def widget_state(app: App):
    return app.get_resource(WidgetState)


class ProcedureSystem:
    def __init__(self, app: App):
        self.picks = app.events.reader(Picked)
        self.widgets = app.events.reader(Widget)
        self.actions = app.events.reader(NeedleAction)
        self.resets = app.events.reader(NeedleReset)
        self.refused = app.events.reader(RotationRefused)
        self.insert_refused = app.events.reader(InsertRefused)
        self.hits = app.events.reader(NeedleHit)
        pres: PackResource = app.resource(PackResource)
        self.scene: NeedleScene = app.resource(NeedleScene)
        self.feedback: Feedback = app.resource(Feedback)
        self.config = pres.pack.section("needle_procedure")
        self.step_list = list(pres.pack.section("steps"))
        self.steps = {s["id"]: s for s in self.step_list}
        self.layout_widgets = {w["name"]: w for w in pres.layout.get("widgets", [])}
        self.last_tick = app.time.tick
        self.lights = {name: "off" for name in self.feedback.lights}
        # the attached view that rides on the needle shows the aiming aid
        needle_name = next(
            (n for n, e in app.resource(EntityIndex).by_name.items() if e == app.resource(NeedleHandles).needle), ""
        )
        self.tip_view = next(
            (v["name"] for v in pres.layout.get("viewports", []) if v.get("attach") == needle_name), ""
        )
        self.fluoro_first = fluoro.fluoro_first(app)
        info = app.get_resource(RunInfo)
        self.replay = bool(info is not None and info.replay)
        ids = [s["id"] for s in self.step_list]
        landmark_steps = [i for i, s in enumerate(self.step_list) if s.get("landmark")]
        self.reset_all_step = self.config.get("reset_all_step") or (ids[landmark_steps[0]] if landmark_steps else "")
        after = landmark_steps[-1] + 1 if landmark_steps else 0
        self.reset_step = self.config.get("reset_step") or (ids[after] if after < len(ids) else "")

    # -- helpers --------------------------------------------------------------------------------
    def state(self, app: App) -> ProcedureState:
        return esper.component_for_entity(app.resource(NeedleHandles).procedure, ProcedureState)

    def needle(self, app: App):
        ent = app.resource(NeedleHandles).needle
        return ent, esper.component_for_entity(ent, Needle), esper.component_for_entity(ent, NeedleState)

    def say(self, app: App, event: str, default_key: str | None = None, **values) -> None:
        """The pack's feedback for `event`, or the built-in message."""
        default = DEFAULTS.get(default_key or event, "")
        self.feedback.fire(app, event, self.lights, default, **values)

    def event(self, app: App, ps: ProcedureState, name: str) -> None:
        """An event a step may be done on: move on to the step after every step that names it."""
        for i, spec in enumerate(self.step_list):
            if name in spec.get("done_on", ()) and i + 1 < len(ps.step_ids):
                self.goto(app, ps, ps.step_ids[i + 1])

    def goto(self, app: App, ps: ProcedureState, step_id: str) -> None:
        """Move forward to `step_id` (never back, except through `restart`)."""
        if step_id not in ps.step_ids:
            return
        k = ps.step_ids.index(step_id)
        if k <= ps.step:
            return
        ps.step = k
        self.show_step(app, ps)

    def restart(self, app: App, ps: ProcedureState, step_id: str) -> None:
        if step_id in ps.step_ids:
            ps.step = ps.step_ids.index(step_id)
            self.show_step(app, ps)

    def show_step(self, app: App, ps: ProcedureState) -> None:
        spec = self.steps.get(ps.step_id, {})
        h = hud(app)
        h.step_title = spec.get("title", ps.step_id)
        h.step_instruction = spec.get("instruction", "")
        if self.fluoro_first and spec.get("fluoro_first_instruction"):  # no ring to line up with
            h.step_instruction = spec["fluoro_first_instruction"]
        h.step_doc = spec.get("docs", "") or h.step_doc
        h.doc_name = h.step_doc or h.doc_name
        # a reading step opens its page in the app (thesis 3.4); later steps keep it a Help press away
        if spec.get("open_docs"):
            h.open_doc()
        else:
            h.close_doc()

    # -- landmarks ------------------------------------------------------------------------------
    def begin_attempt(self, app: App, ps: ProcedureState) -> None:
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
        self.clear_contact(ps)
        hud(app).panel_text = []
        self.say(app, "attempt", attempt=ps.attempt)

    def clear_contact(self, ps: ProcedureState) -> None:
        for name in self.lights:
            self.lights[name] = "off"
        ps.target = "none"
        ps.needle_dist = float("nan")
        ps.first_dist = float("nan")
        ps.hit_point = np.full(3, np.nan)

    def place_landmark(self, app: App, ps: ProcedureState, point) -> None:
        scene = self.scene
        n = len(scene.landmark_ids)
        if ps.placed >= n:
            self.say(app, "landmarks_full")
            return
        k = ps.placed
        p = np.asarray(point, dtype=np.float64)
        ps.landmarks[k] = p
        ps.placed += 1
        self.show_landmark(app, k, p)
        if k == scene.side_from:
            ps.side = scene.side_of(p)
        if k == scene.entry:
            ent, needle, st = self.needle(app)
            needle_sys.place(app, ent, needle, st, p)
        lid = scene.landmark_ids[k]
        self.say(app, f"landmark:{lid}", "landmark", n=k + 1, side=ps.side, id=lid)
        self.event(app, ps, f"landmark:{lid}")

    def show_landmark(self, app: App, k: int, p) -> None:
        handles: NeedleHandles = app.resource(NeedleHandles)
        spec = self.scene.landmark_specs[k]
        if handles.markers[k] is not None:
            tr = esper.try_component(handles.markers[k], Transform)
            if tr is not None:
                tr.position = np.asarray(p, dtype=np.float64).copy()
            mk = esper.try_component(handles.markers[k], Marker)
            if mk is not None:
                mk.visible = True
            lb = esper.try_component(handles.markers[k], Label)
            if lb is not None:
                lb.text = handles.labels[k]
        if handles.planes[k] is not None:
            tr = esper.try_component(handles.planes[k], Transform)
            if tr is not None:
                tr.position = np.asarray(p, dtype=np.float64).copy()
                tr.rotation = Q.look_rotation(
                    np.asarray(spec["plane_normal"], float), np.asarray(spec["plane_up"], float)
                )

    def clear_landmarks(self, app: App, ps: ProcedureState) -> None:
        ps.landmarks[:] = np.nan
        ps.placed = 0
        ps.side = ""
        handles: NeedleHandles = app.resource(NeedleHandles)
        _hide_markers(handles.markers)
        for ent in handles.planes:
            ref = esper.try_component(ent, MeshRef) if ent is not None else None
            if ref is not None:
                ref.visible = False

    # -- the system -----------------------------------------------------------------------------
    def __call__(self, app: App) -> None:
        ps = self.state(app)
        self.lights = {name: "off" for name in self.feedback.lights}
        self.lights.update(ps.lights)
        self._read_aids(app, ps)
        self._read_picks(app, ps)
        for ev in self.widgets.read():
            if ev.name == "next":
                self.next_step(app, ps)
            if self.feedback.has(f"button:{ev.name}"):
                self.say(app, f"button:{ev.name}")
            self.event(app, ps, f"button:{ev.name}")
        self._read_resets(app, ps)
        entry_n = self.scene.entry + 1
        # every refused turn says why, each time (the HUD counts a repeated message: "(x5)"); a click on
        # a locked dial comes here too, through the needle system, which counts it
        for ev in self.refused.read():
            self.say(app, "refused:locked" if ev.reason == "locked" else "refused:not_placed", n=entry_n)
        for ev in self.insert_refused.read():
            self.say(app, f"refused:{ev.reason}", n=entry_n)
        for ev in self.actions.read():
            if ev.kind in ("withdrawn", "turn_held", "turns_dropped"):
                self.say(app, ev.kind, n=int(ev.value))
                continue
            self.begin_attempt(app, ps)
            if ev.kind in ROTATION_WIDGETS:
                self.event(app, ps, f"dial:{ev.kind}")
            elif ev.kind in ("insert", "withdraw") and ev.value > 0:
                self.event(app, ps, "depth")
        for ev in self.hits.read():
            self._contact(app, ps, ev)
        ps.lights = dict(self.lights)
        show = ps.aids_now.get(self.config.get("signals_aid") or "", True)
        h = hud(app)
        for name in self.lights:
            h.set_light(name, self.lights[name] if show else "off")
        self.update_planes(app, ps)
        if not self.replay:  # the aiming aid is drawn, never read back: a replay has no use for it
            self.update_aim(app, ps)
        # time per step, in fixed simulation steps (never the frame's length, which depends on the
        # machine); the clock stops once the target is reached or the attempt is saved
        ticks, self.last_tick = app.time.tick - self.last_tick, app.time.tick
        if not ps.finished and not ps.closed and ticks > 0:
            sid = ps.step_id
            ps.step_times[sid] = ps.step_times.get(sid, 0.0) + ticks * app.time.dt
            ps.elapsed += ticks * app.time.dt

    def _read_aids(self, app: App, ps: ProcedureState) -> None:
        """An aid counts for the attempt if it was on at any time (the trainee had it)."""
        ws = widget_state(app)
        for name in self.config.get("aids", ()):
            on = (
                bool(ws.values.get(name, False))
                if ws is not None and name in ws.values
                else bool(self.layout_widgets.get(name, {}).get("value", False))
            )
            ps.aids[name] = ps.aids.get(name, False) or on
            ps.aids_now[name] = on

    def _read_picks(self, app: App, ps: ProcedureState) -> None:
        """A click on what the next landmark lies on places it; a click elsewhere says where to click."""
        if self.picks is None:
            return
        scene = self.scene
        n = len(scene.landmark_ids)
        for ev in self.picks.read():
            on = scene.landmark_specs[min(ps.placed, n - 1)]["on"] if n else ""
            role = scene.roles.get(on)
            if role is None or ev.entity_name not in role.entities:
                self.say(app, "click_elsewhere", entity=ev.entity_name, n=ps.placed + 1)
                continue
            self.event(app, ps, f"click:{on}")
            if ps.placed < n:
                self.begin_attempt(app, ps)
            self.place_landmark(app, ps, ev.point)

    def _read_resets(self, app: App, ps: ProcedureState) -> None:
        """Reset goes back to the needle's step (to the first when nothing is placed); reset all starts a
        new attempt, with its own aids, times and counts."""
        for ev in self.resets.read():
            self.begin_attempt(app, ps)
            hud(app).panel_text = []
            self.clear_contact(ps)
            ps.finished = False
            if ev.all:
                self.clear_landmarks(app, ps)
                ps.aids = dict(ps.aids_now)
                ps.step_times = {}
                ps.elapsed = 0.0
                ps.finished = False
                self.restart(app, ps, self.reset_all_step)
                self.say(app, "reset_all")
            else:
                self.restart(app, ps, self.reset_step if ps.placed else self.reset_all_step)
                self.say(app, "reset")

    def _contact(self, app: App, ps: ProcedureState, ev) -> None:
        """The needle touched something: what, how far from the target, and whether it is the target."""
        scene = self.scene
        ps.target = ev.object
        ps.needle_dist = float(ev.distance_to_target_mm)
        if not np.isfinite(ps.first_dist):
            ps.first_dist = ps.needle_dist
        ps.hit_point = np.asarray(ev.point, dtype=np.float64)
        radius = scene.target(ps.side or scene.sides[0]).radius
        is_target = ev.role == scene.target_role
        if is_target:
            ps.finished = True
        values = dict(
            what=scene.label(ev.object),
            dist_mm=ev.distance_to_target_mm,
            error_mm=ev.distance_to_target_mm - radius,
            radius_mm=radius,
            side=ps.side,
        )
        if not ev.counted and not is_target:
            # pushed on at the same place: the contact's light, and a line saying it is not another one
            self.feedback.light(f"contact:{ev.role}", self.lights)
            _ent, needle, _st = self.needle(app)
            self.say(app, f"contact_again:{ev.role}", "contact_again", withdraw_mm=needle.recontact_withdraw, **values)
        else:
            self.say(app, f"contact:{ev.role}", "contact:target" if is_target else "contact", **values)
        self.event(app, ps, f"contact:{ev.role}")

    def next_step(self, app: App, ps: ProcedureState) -> None:
        """Next moves on one step, except past a landmark that is not placed yet."""
        lid = self.steps.get(ps.step_id, {}).get("landmark", "")
        ids = self.scene.landmark_ids
        if lid in ids and ps.placed <= ids.index(lid):
            k = ps.placed
            where = next(
                (s.get("instruction", "") for s in self.step_list if s.get("landmark") == ids[k]),
                "",
            )
            self.say(app, "landmark_missing", n=k + 1, instruction=where)
            return
        if ps.step + 1 < len(ps.step_ids):
            self.goto(app, ps, ps.step_ids[ps.step + 1])

    def update_aim(self, app: App, ps: ProcedureState) -> None:
        """The tip view's aiming aid: the entry side's target centre and the tip's distance to it."""

        h = hud(app)
        h.aim_view = self.tip_view
        _ent, _needle, st = self.needle(app)
        if not st.placed:
            # the tip view then shows the crosshair only; the step's instruction says where to click
            h.aim_target, h.aim_note = None, ""
            return
        if self.fluoro_first:
            # no ring and no distance: where the target lies must be read from the X-ray images
            h.aim_target, h.aim_note = None, "fluoroscopy first: guide by the X-ray"
            return
        centre = self.scene.target(ps.side or self.scene.sides[0]).centre
        h.aim_target = tuple(float(c) for c in centre)
        h.aim_note = f"{float(np.linalg.norm(st.tip() - centre)):.1f} mm"

    def update_planes(self, app: App, ps: ProcedureState) -> None:
        on = ps.aids_now.get(self.config.get("planes_aid") or "", False)
        handles: NeedleHandles = app.resource(NeedleHandles)
        for k, ent in enumerate(handles.planes):
            ref = esper.try_component(ent, MeshRef) if ent is not None else None
            if ref is not None:
                ref.visible = bool(on and k < ps.placed)


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


def _check(pack, scene: NeedleScene, index: EntityIndex) -> None:
    """What the pack's tables name must exist: roles, landmarks, steps' events (one line each)."""
    where = f"pack '{pack.name}'"
    if not scene.landmark_ids:
        raise UserError(f"{where}: the needle procedure needs at least one [[landmarks]] (the entry point)")
    declared = set(pack.manifest.get("entities", {}))
    for role in scene.roles.values():
        # a misspelt name would otherwise drop that entity from the role without a word
        unknown = [e for e in role.entities if e not in declared]
        if unknown:
            raise UserError(
                f"{where}: [roles.{role.name}] entities: '{unknown[0]}' is not an entity of the pack "
                f"(entities: {', '.join(sorted(declared))})"
            )
    for sp in scene.landmark_specs:
        role = scene.roles.get(sp["on"])
        if role is None:
            raise UserError(
                f"{where}: landmark '{sp['id']}' is placed on role '{sp['on']}', which has no [roles.{sp['on']}]"
            )
        if not any(index.get(e) is not None for e in role.entities):
            raise UserError(f"{where}: [roles.{sp['on']}] names no entity of the scene ({', '.join(role.entities)})")
        for key in ("marker", "plane_entity"):
            if sp.get(key) and index.get(sp[key]) is None:
                raise UserError(f"{where}: landmark '{sp['id']}' {key} '{sp[key]}' is not an entity of the scene")
    ids = set(scene.landmark_ids)
    events = [(f"steps.{s['id']}.done_on", e) for s in pack.section("steps") for e in s.get("done_on", ())]
    events += [(f"feedback '{f['on']}'", f["on"]) for f in pack.section("feedback")]
    for s in pack.section("steps"):
        if s.get("landmark") and s["landmark"] not in ids:
            raise UserError(f"{where}: step '{s['id']}' landmark '{s['landmark']}' is not a [[landmarks]] id")
    for what, ev in events:
        kind, _, arg = ev.partition(":")
        bad = (
            (kind in ("click", "contact", "contact_again") and arg not in scene.roles)
            or (kind == "landmark" and arg not in ids)
            or (kind == "dial" and arg not in ROTATION_WIDGETS)
            or (kind == "refused" and arg not in ("locked", "not_placed", "in_target", "max_depth"))
            or (kind in ("button",) and not arg)
            or kind
            not in (
                "click",
                "click_elsewhere",
                "landmark",
                "landmarks_full",
                "landmark_missing",
                "dial",
                "depth",
                "withdrawn",
                "turn_held",
                "turns_dropped",
                "contact",
                "contact_again",
                "refused",
                "reset",
                "reset_all",
                "attempt",
                "button",
            )
        )
        if bad:
            raise UserError(
                f"{where}: {what}: '{ev}' is not an event of the needle procedure (docs/needle-procedures.md)"
            )


def plugin(app: App) -> None:

    pres: PackResource = app.resource(PackResource)
    pack = pres.pack
    scene = scene_from_pack(pack)
    app.insert_resource(scene)
    app.insert_resource(
        Feedback(list(pack.section("feedback")), list(pack.section("needle_procedure").get("lights", [])))
    )
    index: EntityIndex = app.resource(EntityIndex)
    with app.active():
        needles = [ent for ent, _ in esper.get_component(Needle)]
        if len(needles) != 1:
            raise UserError(
                f"pack '{pack.name}': the needle procedure needs exactly one entity with a [needle] table, "
                f"found {len(needles)}"
            )
        _check(pack, scene, index)
        step_ids = [s["id"] for s in pack.section("steps")]
        n = len(scene.landmark_ids)
        ps = ProcedureState(step_ids=step_ids, landmarks=np.full((n, 3), np.nan))
        proc = esper.create_entity(Name("procedure"), ps)
        index.by_name["procedure"] = proc
        markers = [index.get(sp["marker"]) if sp.get("marker") else None for sp in scene.landmark_specs]
        planes = [index.get(sp["plane_entity"]) if sp.get("plane_entity") else None for sp in scene.landmark_specs]
        labels = []
        for ent in markers:
            lb = esper.try_component(ent, Label) if ent is not None else None
            labels.append(lb.text if lb is not None else "")
        _hide_markers(markers)
        for ent in planes:
            ref = esper.try_component(ent, MeshRef) if ent is not None else None
            if ref is not None:
                ref.visible = False
    app.insert_resource(NeedleHandles(needles[0], proc, markers, planes, labels))
    needle_sys.plugin(app)
    collision.plugin(app)
    tissue.plugin(app)
    system = ProcedureSystem(app)
    with app.active():
        system.show_step(app, ps)
    app.add_system("procedure", system, order=ORDER_PROCEDURE, name="needle_procedure")
    fluoro.plugin(app)
    assessment.plugin(app)

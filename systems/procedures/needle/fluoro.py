"""The C-arm: projections, single X-ray images, live fluoroscopy and what they cost (thesis 3.2.3).

Stage: procedure (ORDER_FLUORO, after the procedure steps and before the assessment). Reads: Widget
events, ViewTurned events from the "fluoro" viewport, InputState.keys (the pedal), ProcedureState
(the attempt and the entry side), NeedleScene (the side's target: where to centre the arm, its
axis). Writes: the CArm component on the runtime entity "carm", HudState messages. The image
itself is made by the renderer (chainsim.game.render.radiograph) whenever `CArm.image_id` grows; without
a renderer the counts still run.

Controls (widget names; the pack's layout gives them buttons and keys):

    xray_lateral      C-arm to a lateral view of the target's side: the beam runs across the head
                      (along X), detector on the target's side of the midline (X = 0)
    xray_submental    C-arm to the axial-oblique view: the beam comes up the target opening's axis,
                      turned 17.5 degrees toward the target's side (for the foramen ovale, the
                      submental view in which it shows as an oval and the needle tip can be put on it)
    xray_take         one image; it stays on the C-arm view, frozen, until the next image
    fluoro_live       live fluoroscopy on (true) or off (false): a new image 15 times a second
    carm_azimuth      the source's azimuth, degrees (free angles; a drag in the view turns it too)
    carm_elevation    the source's elevation below the axial plane, degrees

The pedal: holding the key PEDAL_KEY runs live fluoroscopy while it is held, like the foot switch.
Exposure is booked per fixed simulation step, so a replay counts the same seconds.

Fluoroscopy first (`fluoro_first`): the pack's [needle_procedure] fluoro_first, or the user's
setting of that name (`play/run --fluoro-first`), takes the target ring and distance off the tip
view, as in theatre where the needle is guided by the images; the assessment records the mode.

Counts belong to the procedure's attempt: when a new attempt begins (ProcedureState.attempt grows),
shots and seconds start again from zero; the arm stays where it is.
"""

from __future__ import annotations

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import Name
from chainsim.components.input_events import Widget
from chainsim.components.resources import EntityIndex, InputState, PackResource, Settings
from chainsim.components.stages import ORDER_FLUORO
from chainsim.components.view_events import ViewTurned
from chainsim.systems.procedures.needle.carm import LIVE_RATE_HZ, CArm
from chainsim.systems.procedures.needle.handles import Feedback, NeedleHandles, hud
from chainsim.systems.procedures.needle.manifest import NeedleScene, ProcedureState, Target


def fluoro_first(app: App) -> bool:
    """Whether this run guides by X-ray only: the user's setting wins over the pack's [needle_procedure]."""
    s = app.resource(Settings)
    if s.get("fluoro_first") is not None:
        return bool(s.get("fluoro_first"))
    return bool(app.resource(PackResource).pack.section("needle_procedure").get("fluoro_first", False))


PEDAL_KEY = "f"
#: degrees the arm turns per pixel dragged in the C-arm view
DEG_PER_PX = 0.4
#: submental-oblique: turned this far from straight up the canal toward the entry side (thesis
#: 3.2.3; clinically the head is turned 15-20 degrees away from the painful side)
OBLIQUE_DEG = 17.5


def _on_minus_x(target: Target) -> bool:
    """Whether the target lies on the -X half (the subject's left in a head frame); a midline target counts."""
    return float(target.centre[0]) <= 0.0


def lateral_pose(target: Target) -> tuple[float, float]:
    """(azimuth, elevation) of a lateral view with the detector on the target's side (the source opposite)."""
    return (0.0, 0.0) if _on_minus_x(target) else (180.0, 0.0)  # detector at -X: the source at +X


def submental_pose(target: Target) -> tuple[float, float]:
    """(azimuth, elevation): the beam up the target's axis, turned OBLIQUE_DEG toward its side."""
    ax = np.asarray(target.axis, float)
    src = -ax / np.linalg.norm(ax)  # the source lies down the canal, under the chin
    elevation = float(np.degrees(np.arcsin(np.clip(-src[2], -1.0, 1.0))))
    azimuth = float(np.degrees(np.arctan2(src[1], src[0])))
    # toward the target's side: -X lies at azimuth 180
    toward = 1.0 if _on_minus_x(target) else -1.0
    return (azimuth + toward * OBLIQUE_DEG) % 360.0, elevation


class CArmSystem:
    def __init__(self, app: App):
        self.widgets = app.events.reader(Widget)
        self.turns = app.events.reader(ViewTurned)
        self.last_tick = app.time.tick
        self.switched = False  # live fluoroscopy switched on with the panel (the pedal needs a held key)

    def carm(self, app: App) -> CArm:
        return esper.component_for_entity(app.resource(EntityIndex).get("carm"), CArm)

    def target(self, app: App) -> Target:
        ps = esper.component_for_entity(app.resource(NeedleHandles).procedure, ProcedureState)
        scene: NeedleScene = app.resource(NeedleScene)
        return scene.target(ps.side or scene.sides[0])

    def centre(self, app: App, carm: CArm) -> None:
        carm.iso = np.asarray(self.target(app).centre, float).copy()

    def image(self, carm: CArm) -> None:
        carm.image_id += 1
        carm.image_pose = (carm.azimuth_deg, carm.elevation_deg, tuple(float(c) for c in carm.iso))

    def __call__(self, app: App) -> None:
        carm = self.carm(app)
        h = hud(app)
        ps = esper.component_for_entity(app.resource(NeedleHandles).procedure, ProcedureState)
        if ps.attempt != carm.attempt:  # a new attempt: its own shots and seconds
            carm.attempt = ps.attempt
            carm.shots, carm.live_s, carm.next_pulse_s = 0, 0.0, 0.0
        live_switch = None
        take = False
        for ev in self.widgets.read():
            if ev.name == "xray_lateral":
                carm.azimuth_deg, carm.elevation_deg = lateral_pose(self.target(app))
                carm.view = "lateral"
                self.centre(app, carm)
                if not app.resource(Feedback).has("button:xray_lateral"):  # the pack's own words, if any
                    h.message("C-arm lateral: take an image (x) to see the needle's depth.")
            elif ev.name == "xray_submental":
                carm.azimuth_deg, carm.elevation_deg = submental_pose(self.target(app))
                carm.view = "submental"
                self.centre(app, carm)
                if not app.resource(Feedback).has("button:xray_submental"):
                    h.message("C-arm up the target's axis: take an image (x) to see the opening end-on.")
            elif ev.name == "carm_azimuth" and isinstance(ev.value, (int, float)) and not isinstance(ev.value, bool):
                carm.azimuth_deg = float(ev.value) % 360.0
                carm.view = "free"
            elif ev.name == "carm_elevation" and isinstance(ev.value, (int, float)) and not isinstance(ev.value, bool):
                carm.elevation_deg = float(np.clip(ev.value, -89.0, 89.0))
                carm.view = "free"
            elif ev.name == "xray_take":
                take = True
            elif ev.name == "fluoro_live":
                live_switch = bool(ev.value) if ev.value is not None else not carm.live
        for ev in self.turns.read():
            if ev.button != "left":
                continue
            carm.azimuth_deg = (carm.azimuth_deg - ev.dx * DEG_PER_PX) % 360.0
            carm.elevation_deg = float(np.clip(carm.elevation_deg + ev.dy * DEG_PER_PX, -89.0, 89.0))
            carm.view = "free"
        if not np.any(carm.iso):
            self.centre(app, carm)
        if take:
            carm.shots += 1
            self.image(carm)
            h.message(f"X-ray {carm.shots}: {carm.exposure_s:.1f} s of exposure, about {carm.dose_mgy:.2f} mGy so far.")
        keys = app.resource(InputState).keys
        pedal = PEDAL_KEY in keys
        if live_switch is not None:
            self.switched = live_switch
        was = carm.live
        carm.live = pedal or self.switched
        if carm.live and not was:
            carm.next_pulse_s = carm.live_s  # the first pulse at once
        if was and not carm.live:
            h.message(f"Live fluoroscopy off: {carm.live_s:.1f} s live this attempt, about {carm.dose_mgy:.2f} mGy.")
        ticks, self.last_tick = app.time.tick - self.last_tick, app.time.tick
        if carm.live and ticks > 0:
            if carm.live_s >= carm.next_pulse_s:
                self.image(carm)
                carm.next_pulse_s += 1.0 / LIVE_RATE_HZ
            carm.live_s += ticks * app.time.dt


def plugin(app: App) -> None:
    """Create the C-arm entity, centred on the first side's target in a lateral view, and its system."""
    index: EntityIndex = app.resource(EntityIndex)
    scene: NeedleScene = app.resource(NeedleScene)
    first = scene.target(scene.sides[0])
    az, el = lateral_pose(first)
    with app.active():
        carm = CArm(azimuth_deg=az, elevation_deg=el, iso=np.asarray(first.centre, float).copy())
        carm.image_pose = (az, el, tuple(float(c) for c in carm.iso))
        index.by_name["carm"] = esper.create_entity(Name("carm"), carm)
    app.add_system("procedure", CArmSystem(app), order=ORDER_FLUORO, name="needle_fluoro")

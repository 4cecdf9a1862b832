"""The ChainMail demos (thesis 5.3 Figs 5.6-5.8) as something a person can try in the window.

`plugin(app)` is what `pack.procedure = "demo"` installs. The pack's bodies are deformable and carry
a scripted `pull` (chainsim.systems.tissue.deformable.Pull) started by a widget; the deformation system
does the pulling and the mouse drags. This procedure only adds what a person needs around them:

* the element each pull drags is marked (a Marker entity that follows it) and the path it will be
  dragged along is drawn as a line from it, so "the marked element" is on screen;
* the `reset` widget puts every body back at rest (a ResetRequest each, served by the deformation
  system) and arms the pulls again; so does a model switch, which restarts the bodies from rest;
* the pack's [[steps]] are shown in turn, each done when what it asks for has happened: `pull` when a
  pull has reached the end of its path, `drag` when a mouse drag on a body has ended. The HUD shows
  the first step not yet done and its docs page is the one Help opens.

Procedure stage, ORDER_PROCEDURE. Reads Widget and Dragged events, Pull and Deformable components.
Writes the marker entities' Transform and PolyLine, Pull run state (on reset), HudState.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import Marker, Name, PolyLine, Transform, to_world
from chainsim.components.events import EventReader
from chainsim.components.hud import HudState
from chainsim.components.input_events import Widget
from chainsim.components.resources import EntityIndex, PackResource
from chainsim.components.stages import ORDER_PROCEDURE
from chainsim.components.view_events import Dragged
from chainsim.systems.engine.errors import UserError
from chainsim.systems.tissue.deformable import Deformable, Pull
from chainsim.systems.tissue.events import ResetRequest

STEP_IDS = ("pull", "drag")
MARK_COLOR = (0.15, 1.0, 0.35, 1.0)
PATH_COLOR = (0.15, 1.0, 0.35, 0.8)
MARK_FRACTION = 0.012  # marker radius as a fraction of the body's size

#: the key page's rows for what no widget shows (chainsim.systems.view.ui.keyhelp)
KEY_ROWS = [
    ("left-drag on the tissue in the Grab view", "pull the element under the cursor with the mouse"),
]

DONE_TITLE = "Done"
DONE_TEXT = "Reset (r) and try again, or switch the tissue model (m) and compare."


@dataclass(slots=True)
class DemoState:
    marks: dict = field(default_factory=dict)  # pulled entity -> marker entity
    steps_done: list = field(default_factory=list)
    resets: int = 0
    # readers (made at build time, by the plugin, so no event is missed)
    widgets: EventReader[Widget] = field(init=False)
    drags: EventReader[Dragged] = field(init=False)


def _world(ent: int, points) -> np.ndarray:
    return to_world(esper.try_component(ent, Transform), points)


def _pull_path(ent: int, p: Pull, d: Deformable) -> np.ndarray:
    """World points: the pulled element now, then the waypoints still ahead of it (all of them before
    the pull starts)."""
    here = _world(ent, d.body.positions[p.resolved])
    if p.done:
        return np.zeros((0, 3))
    way = np.asarray(p.waypoints, np.float64).reshape(-1, 3)
    # before the pull starts the waypoints are in the pull's frame; once started they are local
    if p.started or p.frame == "local":
        way = _world(ent, way)
    if p.started:  # only what is left of the path
        seg = np.linalg.norm(np.diff(np.vstack([_world(ent, p.start_at), way]), axis=0), axis=1)
        k = int(np.searchsorted(np.cumsum(seg), p.travelled, side="right"))
        way = way[k:]
    return np.vstack([here[None, :], way])


def _rearm_all() -> None:
    """Every pull ready to run again from its body's rest shape."""
    for _ent, p in esper.get_component(Pull):
        was_local = p.started
        p.started, p.done, p.travelled = False, False, 0.0
        if was_local and p.frame == "world":
            p.frame = "local"  # the pull system converted its waypoints to the body's frame already


def place_marks(st: DemoState) -> None:
    """Each marker on its pulled element, its line along what is left of the pull's path."""
    for ent, marker in st.marks.items():
        p = esper.component_for_entity(ent, Pull)
        d = esper.component_for_entity(ent, Deformable)
        if p.resolved < 0 or p.resolved >= d.body.n:
            continue
        esper.component_for_entity(marker, Transform).position = _world(ent, d.body.positions[p.resolved])
        line = esper.component_for_entity(marker, PolyLine)
        line.points = _pull_path(ent, p, d)
        line.visible = len(line.points) >= 2


class DemoSystem:
    def __init__(self, st: DemoState):
        self.st = st

    def step_done(self, sid: str, dragged: bool) -> bool:
        if sid == "pull":
            return any(p.done for _e, p in esper.get_component(Pull))
        if sid == "drag":
            return dragged
        return False

    def panel_lines(self, app: App) -> list[str]:
        """What the panel says under the buttons: this demo, the model running it, the other demos."""
        pres: PackResource = app.resource(PackResource)
        scenes = pres.pack.section("scenes")
        lines = [f"Demo: {pres.scene}. {scenes.get(pres.scene, {}).get('description', '')}".strip()]
        models = sorted({d.body.model_used for _e, d in esper.get_component(Deformable)})
        lines.append(f"Tissue model: {', '.join(models)} (m switches)")
        others = [name for name in scenes if name != pres.scene]
        if others:
            rest = "".join(f" or /{name}" for name in others[1:])
            lines.append(f"Other demos: chainsim play {pres.pack.name}/{others[0]}{rest}")
        return lines

    def __call__(self, app: App) -> None:
        st = self.st
        hud = app.get_resource(HudState)
        for ev in st.widgets.read():
            if ev.name in ("reset", "model"):
                if ev.name == "reset":
                    for ent, _d in esper.get_component(Deformable):
                        app.events.emit(ResetRequest(ent))  # the deformation system owns the bodies
                    st.resets += 1
                    if hud is not None:
                        hud.message("Tissue reset: press Pull again, or drag it.", 3.0)
                _rearm_all()
                st.steps_done = []
        dragged = any(ev.phase == "end" and esper.has_component(ev.entity, Deformable) for ev in st.drags.read())
        place_marks(st)
        steps = app.resource(PackResource).pack.section("steps")
        ids = [s["id"] for s in steps]
        for k, sid in enumerate(ids):
            if sid not in st.steps_done and self.step_done(sid, dragged):
                st.steps_done.append(sid)
                if hud is not None:
                    hud.message(f"Done: {steps[k].get('title', sid)}", 4.0)
        if hud is None:
            return
        hud.panel_text = self.panel_lines(app)
        if not steps:
            return
        todo = [k for k, sid in enumerate(ids) if sid not in st.steps_done]
        if todo:
            spec = steps[todo[0]]
            hud.step_title, hud.step_instruction = spec.get("title", ""), spec.get("instruction", "")
            hud.step_doc = spec.get("docs", "")
        else:
            hud.step_title, hud.step_instruction = DONE_TITLE, DONE_TEXT


def plugin(app: App) -> None:
    """Install the demo procedure for a spawned pack (see the module docstring)."""
    pres: PackResource = app.resource(PackResource)
    pack = pres.pack
    unknown = [s["id"] for s in pack.section("steps") if s["id"] not in STEP_IDS]
    if unknown:
        raise UserError(f"pack '{pack.name}': step '{unknown[0]}' is not a demo step; steps are {', '.join(STEP_IDS)}")
    st = DemoState()
    with app.active():
        for ent, (_p, d) in esper.get_components(Pull, Deformable):
            size = float(np.linalg.norm(np.ptp(d.body.rest, axis=0))) if d.body.n else 10.0
            name = esper.try_component(ent, Name)
            marker = esper.create_entity(
                Name(f"{name.value if name else ent}.marked"),
                Transform(),
                Marker(max(size * MARK_FRACTION, 0.5), np.array(MARK_COLOR), "marks", True),
                PolyLine(np.zeros((0, 3)), PATH_COLOR, False, "marks"),
            )
            st.marks[ent] = marker
            index = app.get_resource(EntityIndex)
            if index is not None:
                index.by_name.setdefault(f"{name.value if name else ent}.marked", marker)
        place_marks(st)
    st.widgets = app.events.reader(Widget)
    st.drags = app.events.reader(Dragged)
    app.insert_resource(st)
    hud = app.get_resource(HudState)
    if hud is not None:
        hud.key_rows[:0] = KEY_ROWS
    app.add_system("procedure", DemoSystem(st), order=ORDER_PROCEDURE, name="demo_steps")

"""The cutting trainer (thesis 4.5.2): forceps pull and push layered tissue, scissors cut it along a path.

`plugin(app)` is what `pack.procedure = "cutting"` installs. The pack provides deformable layers (each
a ChainMail surface with one edge fixed), one entity with a `forceps` table and one with a `scissors`
table; the procedure never deforms tissue itself, it asks `chainsim.systems.tissue.deformation` to (GrabRequest,
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
  procedure stage, ORDER_ASSESSMENT (`cutting_assessment`): chainsim.game.trainer.headless.Assessment values,
      and Save attempt: the attempt (from the start or the last Reset tissue) stored through the Records
      resource with the pack's own metrics (.assessment).

Writes: Forceps / Scissors runtime fields, the tools' Transform / Marker / PolyLine, CuttingState
(resource), HudState, Assessment, viewport cameras (ViewState), a Wireframe component on the layers,
DeformationState.drag_type (None). Modules: state (shared), instruments, steps, assessment; this one
installs them.
"""

from __future__ import annotations

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import Name, PolyLine, Transform
from chainsim.components.hud import HudState
from chainsim.components.input_events import MouseMove, Scroll, Widget
from chainsim.components.resources import Assessment, EntityIndex, PackResource
from chainsim.components.stages import ORDER_ASSESSMENT, ORDER_KINEMATICS, ORDER_PROCEDURE
from chainsim.components.view_events import Dragged, Picked
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures.cutting.assessment import AssessmentSystem
from chainsim.systems.procedures.cutting.instruments import ToolsSystem, widget_value
from chainsim.systems.procedures.cutting.state import (
    DONE_EVENTS,
    LEGACY_DONE_ON,
    CuttingState,
    parse_done_on,
    world_positions,
)
from chainsim.systems.procedures.cutting.steps import StepsSystem
from chainsim.systems.procedures.cutting.tools import Forceps, Scissors
from chainsim.systems.tissue.deformable import Deformable
from chainsim.systems.tissue.deformation import DeformationState
from chainsim.systems.tissue.events import Deformed

#: the key page's rows for what no widget shows (chainsim.systems.view.ui.keyhelp)
KEY_ROWS = [
    ("left-drag on the tissue in the Controller", "use the instrument: the forceps grip and carry, the scissors cut"),
    ("click on the tissue", "forceps: grip there; scissors: add a point to the cut path"),
    ("wheel over the Controller while gripping", "pull (up) or push (down) the tissue 1 mm a notch"),
]

# -- plugin ----------------------------------------------------------------------------------------


def check_event(ev) -> None:
    """One scripted event as this procedure will read it: a widget value it would refuse mid-run is
    refused here, before the run (chainsim.game.trainer.headless.check_events; so `validate` reports a
    scene script's bad value)."""
    if isinstance(ev, Widget) and ev.name in ("pull", "pull_by", "push"):
        widget_value(ev.name, ev.value)


def plugin(app: App) -> None:
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
        # a step says what completes it (`done_on`); one without it keeps the meaning of its id
        step_ids = [s["id"] for s in pack.section("steps")]
        for s in pack.section("steps"):
            if not s.get("done_on") and s["id"] not in LEGACY_DONE_ON:
                raise UserError(
                    f"pack '{pack.name}': step '{s['id']}' says nothing that completes it; give it "
                    f'done_on = ["KIND:MM"] (KIND: {", ".join(DONE_EVENTS)}) or use a step id of '
                    f"{', '.join(LEGACY_DONE_ON)}"
                )
        st.step_events = [parse_done_on(s, f"steps.{s['id']}.done_on") for s in pack.section("steps")]
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
        hud.key_rows[:0] = KEY_ROWS
    app.add_system("simulation", ToolsSystem(app, st), order=ORDER_KINEMATICS, name="cutting_tools")
    app.add_system("procedure", StepsSystem(st), order=ORDER_PROCEDURE, name="cutting_steps")
    app.add_system("procedure", AssessmentSystem(st, app), order=ORDER_ASSESSMENT, name="cutting_assessment")

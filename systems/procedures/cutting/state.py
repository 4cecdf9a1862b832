"""What the cutting trainer's systems share (thesis 4.5.2): its constants, run state and tissue geometry helpers."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import MeshRef, Transform, to_world
from chainsim.components.events import EventReader
from chainsim.components.input_events import MouseMove, Scroll, Widget
from chainsim.components.resources import PackResource
from chainsim.components.view_events import Dragged, Picked
from chainsim.systems.engine.errors import UserError
from chainsim.systems.tissue.deformable import Deformable
from chainsim.systems.tissue.events import Deformed

TOOLS = ("forceps", "scissors")
MOVED_MM = 0.01  # an element this far from rest counts as displaced
#: what completes a step without `done_on` (packs written before steps said it): its id's events
LEGACY_DONE_ON = {"pull": ["carried:5"], "cut": ["cut:20"], "open": ["opened:10"]}
#: the events a cutting step's `done_on` may name, each with a distance in mm (docs/making-a-pack.md)
DONE_EVENTS = {
    "carried": "the forceps have carried gripped tissue at least MM from where the grip began",
    "cut": "the scissors' path, with links removed, is at least MM long",
    "opened": "a grip on a layer that has been cut has carried it at least MM",
}


def parse_done_on(step: dict, where: str) -> list[tuple[str, float]]:
    """A cutting step's completing events as (kind, mm), or one UserError line naming what is wrong."""
    names = step.get("done_on") or LEGACY_DONE_ON.get(step.get("id", ""), [])
    out = []
    for ev in names:
        kind, _, arg = ev.partition(":")
        try:
            mm = float(arg)
        except ValueError:
            mm = float("nan")
        if kind not in DONE_EVENTS or not math.isfinite(mm) or mm < 0:
            raise UserError(
                f"{where}: '{ev}' is not an event of the cutting procedure (expected KIND:MM with KIND one of "
                f"{', '.join(DONE_EVENTS)} and MM a distance >= 0, e.g. 'carried:5')"
            )
        out.append((kind, mm))
    return out


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
    step_events: list = field(default_factory=list)  # per step: [(kind, mm)] that complete it
    steps_done: list = field(default_factory=list)  # in the order they were done
    cut_length: float = 0.0  # mm since the last reset
    wireframe: bool = False
    resets: int = 0
    uses: list[ToolUse] = field(default_factory=list)  # in order
    open_use: ToolUse | None = None
    path_entity: int = -1  # runtime entity drawing the current cut path
    pending_view: str = ""  # tool whose best view is still to be applied
    drag_origin: tuple | None = None  # (tip, grab point) at the start of a forceps drag
    hover: np.ndarray | None = None  # world point of the tissue under the cursor (the idle tool sits there)
    # readers (made at build time, by the plugin, so no event is missed)
    widgets: EventReader[Widget] = field(init=False)
    picks: EventReader[Picked] = field(init=False)
    drags: EventReader[Dragged] = field(init=False)
    scrolls: EventReader[Scroll] = field(init=False)
    moves: EventReader[MouseMove] = field(init=False)
    deformed: EventReader[Deformed] = field(init=False)
    tool_widgets: EventReader[Widget] = field(init=False)
    # cached assessment per layer: entity -> (version, alive count, values)
    cache: dict = field(default_factory=dict)


# -- geometry helpers ------------------------------------------------------------------------------


def world_positions(ent: int, d: Deformable) -> np.ndarray:
    return to_world(esper.try_component(ent, Transform), d.body.positions)


def nearest_element(ent: int, d: Deformable, point) -> tuple[int, float]:
    """(element id, distance in mm) of the element of `d` nearest to a world point."""
    w = world_positions(ent, d)
    d2 = np.sum((w - np.asarray(point, dtype=np.float64)) ** 2, axis=1)
    i = int(np.argmin(d2))
    return i, math.sqrt(float(d2[i]))


def element_normal(app: App, ent: int, d: Deformable, element: int) -> np.ndarray:
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
    b = d.body
    links = b.graph.links[b.alive]
    if len(links) == 0:
        return 1.0
    cur = np.linalg.norm(b.positions[links[:, 1]] - b.positions[links[:, 0]], axis=1)
    rest = np.linalg.norm(b.rest[links[:, 1]] - b.rest[links[:, 0]], axis=1)
    ok = rest > 1e-12
    return float(np.max(cur[ok] / rest[ok])) if np.any(ok) else 1.0

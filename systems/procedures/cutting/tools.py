"""Instruments of the cutting trainer (thesis 4.5.2): forceps that grab, pull and push one element of a
tissue layer, and scissors that cut along a path of touched points. Plain data; the behaviour lives in
`chainsim.systems.procedures.cutting.procedure`.

The manifest keys set how a tool behaves (speeds, grab reach, blade size); the runtime fields hold what
it is doing now (which element it holds, where its tip is, the cut path so far) and what it has done
(uses, times), so a run's digest covers the tools as well as the tissue.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from chainsim.components.registry import component, prop


def _vec():
    return np.zeros(3)


@component(
    "forceps",
    help="Forceps tool of the cutting trainer (thesis 4.5.2): grabs the element nearest to "
    "where the tissue is touched and pulls or pushes it; the entity's marker shows the tip.",
)
@dataclass(slots=True)
class Forceps:
    speed: float = prop(
        "float", 40.0, units="mm/s", help="Fastest the tip follows the hand (one grab per step).", min=1e-3
    )
    reach: float = prop(
        "float", 6.0, units="mm", help="A touch grabs the nearest element within this distance.", min=0.0
    )
    lift: float = prop("float", 12.0, units="mm", help="Height of the drawn shaft above the tip.", min=0.0)
    push_step: float = prop(
        "float", 2.0, units="mm", help="How far one press of the Push button pushes the held tissue in.", min=0.0
    )
    scroll_step: float = prop(
        "float", 1.0, units="mm", help="How far one wheel notch pulls (up) or pushes (down) the held tissue.", min=0.0
    )
    view_yaw: float = prop(
        "float", 30.0, units="deg", help="Yaw of the frozen views when the forceps are chosen (thesis 4.5.2)."
    )
    view_pitch: float = prop(
        "float", 35.0, units="deg", help="Pitch of the frozen views when the forceps are chosen.", min=-89.0, max=89.0
    )
    # runtime state
    held_entity: int = -1  # deformable entity held, -1 when open
    held_element: int = -1
    tip: np.ndarray = field(default_factory=_vec)  # world mm
    target: np.ndarray = field(default_factory=_vec)  # world mm the tip moves towards
    grip_start: np.ndarray = field(default_factory=_vec)  # world mm where the current grip began
    moving: bool = False
    release_on_arrival: bool = False  # a drag has ended: open once the tip reaches the hand
    uses: int = 0
    use_start: float = 0.0  # sim time the current grip started
    time_used: float = 0.0  # seconds spent gripping, all uses


@component(
    "scissors",
    help="Scissors tool of the cutting trainer (thesis 4.5.2): each touched point extends the "
    "cut path and links the path crosses are removed from the touched layer only.",
)
@dataclass(slots=True)
class Scissors:
    min_step: float = prop(
        "float", 0.5, units="mm", help="Path points closer than this to the last one are skipped.", min=0.0
    )
    blade: float = prop("float", 10.0, units="mm", help="Length of the drawn blade.", min=0.0)
    view_yaw: float = prop(
        "float", 0.0, units="deg", help="Yaw of the frozen views when the scissors are chosen (thesis 4.5.2)."
    )
    view_pitch: float = prop(
        "float", 75.0, units="deg", help="Pitch of the frozen views when the scissors are chosen.", min=-89.0, max=89.0
    )
    depth: float = prop(
        "float",
        4.0,
        units="mm",
        help="How far the blade reaches either side of the path along its depth direction (thin "
        "layers: less than the gap to the next layer is not needed, each cut names one layer).",
        min=0.0,
    )
    # runtime state
    stroke_entity: int = -1  # layer being cut by the current stroke, -1 when the blade is lifted
    stroke: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # world mm, points of the current stroke
    uses: int = 0
    use_start: float = 0.0
    time_used: float = 0.0
    path_length: float = 0.0  # mm of cut path, all strokes
    links_cut: int = 0

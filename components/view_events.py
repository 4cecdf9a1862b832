"""Events the view system emits for procedures and tools (the output side of picking and widgets).

`Picked` is the one event consumers of clicks on the scene read (a procedure places its marked points on
a surface with it, thesis 3.3.4; the cutting trainer grabs tissue, 4.5.2). It is emitted once per click
(button pressed and released without moving more than a few pixels) on a visible, pickable mesh in a
3-D viewport, and once per scripted `PickPoint` (snapped to the entity's surface, `viewport` = "").

`Dragged` follows a left-button drag that starts on a surface in a viewport whose camera is not moved
by the mouse (fixed or attached viewports, or any viewport with `interactive = false` for the camera):
phase "start" at the press, "move" for each drag event, "end" at the release. `point` is where the
cursor ray meets the plane through `grab_point` facing the camera, so a drag moves the grabbed point
parallel to the screen.

`ViewTurned` reports a mouse drag in a viewport that draws an image of its own rather than a camera
the mouse moves (a "fluoro" viewport: the C-arm view); whoever owns that image decides what the drag
turns (the C-arm's angles).

Widget events are the input vocabulary's own `chainsim.components.input_events.Widget`; the view system emits them
directly on the event queue when a widget is clicked, dragged or its key pressed.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Picked:
    viewport: str
    entity: int
    entity_name: str
    triangle: int
    point: tuple[float, float, float]  # world mm, on the surface
    button: str = "left"


@dataclass(frozen=True, slots=True)
class Dragged:
    viewport: str
    entity: int
    entity_name: str
    phase: str  # "start", "move", "end"
    triangle: int  # triangle grabbed at the start
    grab_point: tuple[float, float, float]  # world mm where the drag started
    point: tuple[float, float, float]  # world mm under the cursor now (see module docstring)
    button: str = "left"


@dataclass(frozen=True, slots=True)
class LayerChanged:
    """A visibility group was switched (by a toggle widget or code)."""

    layer: str
    visible: bool


@dataclass(frozen=True, slots=True)
class WidgetRefused:
    """A disabled widget was clicked; its state did not change (procedures may say why)."""

    name: str


@dataclass(frozen=True, slots=True)
class ViewTurned:
    """A drag in an image viewport (kind "fluoro"), in window pixels: right and up are positive."""

    viewport: str
    dx: float
    dy: float
    button: str = "left"

"""A scripted attempt made into the device input a person gives the trainer window: clicks and drags.

Scripts name what to do (``pick`` a point on the face, set a ``widget`` to a value); the window only
ever sees the mouse. ``gestures`` turns each script event into the pointer gesture that does the same
in a window of the pack's default size: a click on the pixel that shows a picked point in the first
3-D view that picks, a click on a button, a click on a slider's track at the value, a press on a
dial and a drag that turns it the rest of the way. ``HUMAN`` paces the gestures as a person makes
them (docs/limits.md, "Input a person can make"); ``pack builders`` use ``INSTANT`` to keep a
script's own times. Records tests and ``chainsim bench records`` upload attempts made this way,
because a records server accepts only the window's form of input.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from chainsim.components.app import App
from chainsim.components.input_events import MouseButton, MouseDrag, MouseMove, PickPoint, Widget
from chainsim.systems.engine.errors import UserError
from chainsim.systems.view.cameras import ViewState, main_view
from chainsim.systems.view.ui import docbox
from chainsim.systems.view.ui import widgets as wd


@dataclass(frozen=True)
class Pace:
    """Seconds from one gesture's start to the next's at least (``gap_s``), from reaching a target to
    pressing (``aim_s``) and from pressing to releasing (``hold_s``)."""

    gap_s: float
    aim_s: float
    hold_s: float


#: a deliberate person: under two aimed clicks a second, a tenth of a second's press
HUMAN = Pace(gap_s=0.7, aim_s=0.15, hold_s=0.1)
#: the script's own times, gestures 10 ms apart (what the packs' generated mouse scripts use)
INSTANT = Pace(gap_s=0.0, aim_s=0.01, hold_s=0.02)


def _click(t: float, x: float, y: float, pace: Pace, drag_dx: float | None = None) -> list[tuple[float, Any]]:
    out: list[tuple[float, Any]] = [(t, MouseMove(x, y)), (t + pace.aim_s, MouseButton(x, y, "left", True))]
    x_end = x
    if drag_dx:
        x_end = x + drag_dx
        out.append((t + pace.aim_s + pace.hold_s / 2, MouseDrag(x_end, y, drag_dx, 0.0, "left")))
    out.append((t + pace.aim_s + pace.hold_s, MouseButton(x_end, y, "left", False)))
    return out


def _widget(ev: Widget, placed: dict, values: dict) -> tuple[float, float, float | None]:
    """Where to press for a widget event, and how far to drag after (dials)."""
    if ev.name not in placed:
        raise UserError(f"no widget named {ev.name!r} in the window's panels")
    p = placed[ev.name]
    kind = p.spec["kind"]
    cx, cy = p.rect.x + p.rect.w / 2, p.rect.y + p.rect.h / 2
    if kind in ("button", "toggle"):
        return cx, cy, None
    lo, hi = float(p.spec.get("min", 0.0)), float(p.spec.get("max", 1.0))
    if kind == "slider":
        x0, x1 = wd.track(p)
        x = x0 + (float(ev.value) - lo) / (hi - lo) * (x1 - x0)
        values[ev.name] = wd.slider_value(p, x)
        return x, cy, None
    if kind == "dial":
        # the press itself steps the dial once (right half: up); the drag turns it the rest of the way
        after_press = wd.click_value(p, cx, values.get(ev.name, 0.0))
        values[ev.name] = float(ev.value)
        return cx, cy, (float(ev.value) - after_press) * max(p.rect.w, 1) / (hi - lo)
    raise UserError(f"no mouse gesture for a {kind} widget ({ev.name})")


def gestures(
    app: App, events: list[tuple[float, Any]], pace: Pace = HUMAN, *, close_page: bool = True
) -> list[tuple[float, Any]]:
    """The window's device events for script ``events`` in ``app``'s started (unstepped) scene.

    ``close_page``: first close the page a reading step opens over the face, as a trainee does.
    Device events in ``events`` are kept (moved later with the rest when the pace shifts them)."""
    vs = app.resource(ViewState)
    pickers = [(vp, vp.camera) for vp in vs.viewports if vp.is_3d and vp.camera is not None and vp.picks]
    placed = {p.spec["name"]: p for ps in vs.panels.values() for p in ps}
    values = dict(app.resource(wd.WidgetState).values)
    out: list[tuple[float, Any]] = []
    t_next = 0.0
    if close_page:
        main = main_view(vs)
        if main is None:
            raise UserError("the scene has no view to show a page in")
        close = docbox.buttons(docbox.box(main.rect))["close"]
        out += _click(0.05, close.x + close.w / 2, close.y + close.h / 2, pace)
        t_next = 0.05 + pace.gap_s
    shift = 0.0
    for t, ev in events:
        start = max(t + shift, t_next)
        shift = start - t
        if isinstance(ev, PickPoint):
            if not pickers:
                raise UserError("the scene has no 3-D view to click a point in")
            vp, camera = pickers[0]
            # window events carry whole pixels and aim through pixel centres: click the pixel holding the point
            px, py, _ = camera.project(np.asarray(ev.point, float)[None], vp.rect)[0]
            out += _click(start, float(np.floor(px)), float(np.floor(py)), pace)
        elif isinstance(ev, Widget):
            x, y, dx = _widget(ev, placed, values)
            out += _click(start, x, y, pace, drag_dx=dx)
        else:
            out.append((start, ev))
            continue
        t_next = start + pace.gap_s
    return out


def save_click(app: App, after: float, pace: Pace = HUMAN) -> list[tuple[float, Any]]:
    """A click on the Save button ``pace.gap_s`` after ``after`` (the last gesture's start)."""
    x, y, _ = _widget(
        Widget("save"), {p.spec["name"]: p for ps in app.resource(ViewState).panels.values() for p in ps}, {}
    )
    return _click(after + pace.gap_s, x, y, pace)

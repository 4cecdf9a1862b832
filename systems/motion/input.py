"""Input stage, first system: releases due input events and keeps InputState current.

Stage: input (ORDER_INPUT). Reads: PendingInput (script, replay or window events, timestamped in
simulated seconds), Time. Writes: InputState; emits each released event on the EventQueue, in
order, so later systems (cameras, widgets, needle) read them like any other event. Every released
event is also appended to InputLog, which is what `--record` saves.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from chainsim.components.app import App
from chainsim.components.input_events import Key, MouseButton, MouseDrag, MouseMove, Resize, Scroll
from chainsim.components.resources import InputState, PendingInput, Time
from chainsim.components.stages import ORDER_INPUT


@dataclass(slots=True)
class InputLog:
    """(t, event) for every event released so far."""

    items: list = field(default_factory=list)


def input_system(app: App) -> None:
    t: Time = app.time
    state: InputState = app.resource(InputState)
    pending: PendingInput = app.resource(PendingInput)
    log: InputLog = app.resource(InputLog)
    now = t.sim_time
    for ev in pending.due(now):
        if isinstance(ev, (MouseMove, MouseDrag, Scroll)):
            state.mouse = (ev.x, ev.y)
        elif isinstance(ev, MouseButton):
            state.mouse = (ev.x, ev.y)
            (state.buttons.add if ev.pressed else state.buttons.discard)(ev.button)
        elif isinstance(ev, Key):
            (state.keys.add if ev.pressed else state.keys.discard)(ev.key)
        elif isinstance(ev, Resize):
            state.window_size = (ev.width, ev.height)
        log.items.append((now, ev))
        app.events.emit(ev)


def plugin(app: App) -> None:
    app.insert_resource(InputLog())
    app.add_system("input", input_system, order=ORDER_INPUT, name="input")

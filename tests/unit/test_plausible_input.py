"""Uploads in the window's form only, and input a person's hands can give (docs/limits.md).

The rules are checked on drawn input: any session paced as a person paces it (presses at least
0.2 s apart, short drags) passes every rule, however long; the same session sped up past the
rules' rates is flagged, and a script's events or another step are refused in one line.
"""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.game.records import plausible
from chainsim.systems.engine.errors import UserError

DT = 1.0 / 120.0


def click(t: float, x: float, y: float, hold: float = 0.1) -> list[dict]:
    return [
        {"t": t, "kind": "mouse_move", "x": x, "y": y},
        {"t": t, "kind": "mouse_button", "x": x, "y": y, "button": "left", "pressed": True},
        {"t": t + hold, "kind": "mouse_button", "x": x, "y": y, "button": "left", "pressed": False},
    ]


gestures = st.lists(
    st.tuples(
        st.floats(0.2, 5.0),  # seconds since the previous gesture: a person's pace or slower
        st.floats(0, 1280),
        st.floats(0, 800),
        st.sampled_from(["click", "key", "drag"]),
        st.floats(-300, 300),
    ),
    min_size=1,
    max_size=60,
)


def session(drawn, speed: float = 1.0) -> list[dict]:
    out, t = [], 0.0
    for gap, x, y, kind, dx in drawn:
        t += gap / speed
        if kind == "click":
            out += click(t, x, y, 0.1 / speed)
        elif kind == "key":
            out += [{"t": t, "kind": "key", "key": "i", "pressed": True}]
            out += [{"t": t + 0.08 / speed, "kind": "key", "key": "i", "pressed": False}]
        else:
            out += click(t, x, y, 0.1 / speed)
            out.insert(-1, {"t": t + 0.05 / speed, "kind": "mouse_drag", "x": x + dx, "y": y, "dx": dx, "dy": 0.0})
    return out


@settings(max_examples=60, deadline=None)
@given(gestures)
def test_a_session_at_a_persons_pace_is_never_flagged(drawn):
    events = session(drawn)
    assert plausible.flags(events, events[-1]["t"] + 3.0, 2.5) == []


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 1280), st.floats(0, 800)), min_size=12, max_size=40))
def test_aimed_clicks_faster_than_pointing_allows_are_flagged(points):
    # every target far from the one before: an aimed click each 0.1 s
    events, t, last = [], 0.0, None
    for x, y in points:
        if last is not None and abs(x - last[0]) + abs(y - last[1]) < 2 * plausible.AIMED_PX:
            x = (x + 640) % 1280
        events += click(t, x, y, 0.03)
        t += 0.1
        last = (x, y)
    assert any("clicks on separate targets" in f for f in plausible.flags(events, 60.0, 0.0))


def test_a_flood_of_key_presses_and_a_flung_drag_are_flagged():
    keys = [{"t": i * 0.02, "kind": "key", "key": "Up", "pressed": p} for i in range(60) for p in (True, False)]
    assert any("presses within one second" in f for f in plausible.flags(keys, 60.0, 0.0))
    drags = [{"t": i * 0.01, "kind": "mouse_drag", "x": 0, "y": 0, "dx": 400.0, "dy": 0.0} for i in range(60)]
    assert any("dragged" in f for f in plausible.flags(drags, 60.0, 0.0))
    # the same drags spread over ten seconds are a hand's
    slow = [{**d, "t": i * 0.2} for i, d in enumerate(drags)]
    assert plausible.flags(slow, 60.0, 0.0) == []


def test_an_attempt_shorter_than_the_packs_minimum_is_flagged():
    events = click(0.0, 10, 10)
    assert plausible.flags(events, 0.72, 2.5) == [
        "the attempt took 0.72 s; this procedure cannot be done in under 2.5 s"
    ]
    assert plausible.flags(events, 2.6, 2.5) == []
    assert plausible.flags(events, 0.72, 0.0) == []  # a pack without a minimum


def test_script_events_and_a_foreign_step_are_refused_in_one_line():
    rec = {"dt": DT, "event": click(0.5, 1, 2)}
    plausible.window_form(rec, DT)
    for bad in ({"t": 1, "kind": "widget", "name": "save"}, {"t": 1, "kind": "pick", "entity": "skin"}):
        with pytest.raises(UserError, match=f"a '{bad['kind']}' event, which the window never records"):
            plausible.window_form({"dt": DT, "event": [*rec["event"], bad]}, DT)
    with pytest.raises(UserError, match="the recording's step is 0.1 s but the pack's"):
        plausible.window_form({"dt": 0.1, "event": rec["event"]}, DT)

"""Whether an uploaded recording is in the form the window records, and whether a person could have made it.

A replayed upload proves that its recording produces its figures, not that a person produced the
recording. Two checks close that gap as far as input alone can (docs/limits.md, "Input a person can
make", gives each threshold's reasoning):

* ``window_form`` refuses what the trainer window never records: script-level events (``widget``
  presses, ``pick`` of an exact surface point) and a step other than the pack's own. Such a
  recording is refused with one line; it was made by a script, not at the window.
* ``flags`` names input beyond a person's hands: more presses in one second than the fastest
  tapping, more aimed clicks at separate targets in one second than pointing allows, more pointer
  travel while dragging in one second than a hand moves a mouse, or an attempt saved sooner than
  the pack's own minimum (``[records] min_attempt_s``). A flagged attempt is stored and shown, but
  counts in no class figure until a trainer accepts it.

The rules use one-second windows, not single intervals: the window stamps events with the frame
they arrive in, so two quick presses may share a time stamp on a slow frame, but no frame is a
second long while a person plays.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from chainsim.systems.engine.errors import UserError

#: the device events the trainer window (and the browser trainer) records; everything else is a script's
WINDOW_EVENTS = frozenset({"mouse_move", "mouse_button", "mouse_drag", "scroll", "key", "resize"})
#: two steps are "the same" when they differ by less than this (seconds): JSON keeps 17 digits
DT_TOLERANCE = 1e-9

#: presses (keys and mouse buttons) in any one second: sustained tapping peaks near 10-14 a second
#: with one finger and about 20 with two hands alternating
MAX_PRESSES_PER_S = 25
#: mouse presses on targets at least AIMED_PX apart in any one second: an aimed movement and click
#: takes at least about 0.2 s (Fitts' law with the shortest published intercepts)
MAX_AIMED_CLICKS_PER_S = 6
AIMED_PX = 40.0
#: pointer travel while dragging in any one second (pixels): 20,000 px is the width of a 1280-px
#: window crossed 15 times, several times faster than a hand moves a mouse
MAX_DRAG_PX_PER_S = 20000.0


def window_form(recording: dict[str, Any], pack_dt: float, session_kinds: Iterable[str] = ()) -> None:
    """UserError naming the first thing in ``recording`` the window never records, if any. ``session_kinds``:
    kinds of event a study session sets itself, which its caller checks (chainsim.game.study.protocol)."""
    allowed = WINDOW_EVENTS | frozenset(session_kinds)
    dt = recording.get("dt")
    if not isinstance(dt, (int, float)) or abs(float(dt) - pack_dt) > DT_TOLERANCE:
        raise UserError(
            f"the recording's step is {dt!r} s but the pack's is {pack_dt!r} s: the window records at the pack's "
            "own step, so this recording was not made at the window"
        )
    for i, ev in enumerate(recording.get("event") or []):
        kind = ev.get("kind") if isinstance(ev, dict) else None
        if kind not in allowed:
            raise UserError(
                f"recording event {i + 1} is a {kind!r} event, which the window never records (it records "
                f"{', '.join(sorted(WINDOW_EVENTS))}): a scripted attempt cannot be uploaded as a trainee's"
            )


def _presses(events: list[dict]) -> list[dict]:
    return [e for e in events if e.get("kind") in ("key", "mouse_button") and e.get("pressed", True)]


def _most_in_a_second(times: list[float], weights: list[float] | None = None) -> float:
    """The largest sum of ``weights`` (1 each by default) over events in any window of one second."""
    w = weights or [1.0] * len(times)
    best = total = 0.0
    lo = 0
    for hi, t in enumerate(times):
        total += w[hi]
        while t - times[lo] >= 1.0:
            total -= w[lo]
            lo += 1
        best = max(best, total)
    return best


def _aimed_clicks(events: list[dict]) -> list[float]:
    """Times of mouse presses each at least AIMED_PX from the previous press."""
    out, last = [], None
    for e in events:
        if e.get("kind") != "mouse_button" or not e.get("pressed", True):
            continue
        x, y = float(e.get("x", 0.0)), float(e.get("y", 0.0))
        if last is None or math.hypot(x - last[0], y - last[1]) >= AIMED_PX:
            out.append(float(e["t"]))
        last = (x, y)
    return out


def flags(events: Iterable[dict], duration_s: float | None, min_attempt_s: float) -> list[str]:
    """Why this input is beyond a person's (one line per rule broken; empty when none is)."""
    evs = sorted(
        (e for e in events if isinstance(e, dict) and isinstance(e.get("t"), (int, float))), key=lambda e: e["t"]
    )
    out = []
    presses = _most_in_a_second([float(e["t"]) for e in _presses(evs)])
    if presses > MAX_PRESSES_PER_S:
        out.append(f"{presses:.0f} presses within one second (a person manages at most {MAX_PRESSES_PER_S})")
    aimed = _most_in_a_second(_aimed_clicks(evs))
    if aimed > MAX_AIMED_CLICKS_PER_S:
        out.append(
            f"{aimed:.0f} clicks on separate targets within one second (a person manages at most "
            f"{MAX_AIMED_CLICKS_PER_S})"
        )
    drags = [e for e in evs if e.get("kind") == "mouse_drag"]
    travel = _most_in_a_second(
        [float(e["t"]) for e in drags], [math.hypot(float(e.get("dx", 0)), float(e.get("dy", 0))) for e in drags]
    )
    if travel > MAX_DRAG_PX_PER_S:
        out.append(
            f"the pointer dragged {travel:.0f} px within one second (a hand moves at most {MAX_DRAG_PX_PER_S:.0f})"
        )
    if duration_s is not None and min_attempt_s > 0 and duration_s < min_attempt_s:
        out.append(f"the attempt took {duration_s:.2f} s; this procedure cannot be done in under {min_attempt_s:g} s")
    return out


def markdown() -> str:
    """The section of docs/limits.md that states these rules, with their thresholds, and why."""
    table = [
        (
            "Presses (keys and mouse buttons)",
            f"more than {MAX_PRESSES_PER_S} in one second",
            "sustained finger tapping peaks near 10-14 a second with one finger "
            "and about 20 with two hands alternating",
        ),
        (
            f"Clicks on separate targets (at least {AIMED_PX:g} px from the previous press)",
            f"more than {MAX_AIMED_CLICKS_PER_S} in one second",
            "an aimed movement and click takes at least about 0.2 s "
            "(Fitts' law with the shortest published intercepts)",
        ),
        (
            "Pointer travel while dragging",
            f"more than {MAX_DRAG_PX_PER_S:,.0f} px in one second",
            "the width of a 1280-px window crossed 15 times, several times faster than a hand moves a mouse",
        ),
        (
            "The attempt's duration",
            "under the pack's `[records] min_attempt_s`",
            "the procedure's own minimum: its aimed clicks at 0.3 s each and the tool's travel at its top speed",
        ),
    ]
    rows = "\n".join(f"| {rule} | {limit} | {why} |" for rule, limit, why in table)
    return f"""## Input a person can make

A records server replays each upload to compute its result (docs/records-server.md, "Provenance"),
which proves that the recording produces the figures, not that a person produced the recording.
Two checks on uploads from the window (`chainsim.game.records.plausible`; attempts made in the
browser trainer are the server's own and are not checked):

- **The window's form.** The window records device events only (`mouse_move`, `mouse_button`,
  `mouse_drag`, `scroll`, `key`, `resize`) at the pack's own step (`[settings] dt`). A recording
  with a `widget` or `pick` event, or another step, was made by a script, and the upload is refused
  with one line naming the event or the step.
- **A person's hands.** An attempt is stored but flagged (counted in no class figure until its
  trainer accepts it; one audit line) when its input breaks any of these, each over any one second
  of the session (the window stamps events with the frame they arrive in, so single intervals are
  not trusted; no frame is a second long while a person plays):

| Rule | Threshold | Why |
|---|---|---|
{rows}

Single intervals between events are not judged: the window stamps each event with the simulated
time of the frame it arrives in, and a frame that stalls (an X-ray image being drawn, kernels
compiling) advances the simulation by at most 0.1 s however long it lasts, so a person's clicks
during a 1.5 s stall arrive milliseconds apart. Over one second such bunching stays far below the
thresholds above, which also allow for a simulation running at half speed on a slow machine (a
person's three aimed clicks a second then read as six). What these rules catch is input made by a
program and sped up; input made by a program at a person's pace cannot be told from a person's,
which is why a class or a study can require witnessed attempts.

The needle packs' minimum is 2.5 s: after the first point marked on the face, six aimed clicks (two more points, two
dials, the insertion, Save) at 0.3 s, and the needle's travel to the target at its `insert_speed`
(prp: 69 mm at 100 mm/s; mental-block: 17 mm at 20 mm/s), rounded down. The pack's own scripted
attempt at five times its speed breaks the clicks rule and the minimum; the same attempt made at a
person's pace (`chainsim.game.trainer.windowform.HUMAN`, under two aimed clicks a second) breaks none.

"""

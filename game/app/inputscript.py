"""Input scripts and session recordings (format described in docs/input-scripts.md).

An input script is TOML (or JSON) with `format = 1` and an array of events:

    format = 1
    [[event]]
    t = 0.5                 # simulated seconds
    kind = "widget"         # mouse_move, mouse_button, mouse_drag, scroll, key, widget, resize, pick
    name = "insert"
    value = 1.0

A recording (`--record FILE`) is JSON: the same events plus the pack, scene, dt, steps and the
final digest, so `chainsim replay FILE` can run it again and compare.

Both are read through chainsim.engine.datafile (size, nesting and number limits) and every event
is checked (times finite, in order and at most MAX_TIME; at most MAX_EVENTS events).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from chainsim.components.input_events import event_from_dict, event_to_dict
from chainsim.engine import datafile, limits
from chainsim.engine.errors import UserError
from chainsim.game.app.outputs import write_text_atomic

FORMAT = 1


def parse_events(data: dict, where: str) -> list[tuple[float, Any]]:
    if not isinstance(data, dict):
        raise UserError(f"{where}: expected a table with 'format' and 'event' entries")
    fmt = data.get("format")
    if fmt != FORMAT:
        raise UserError(f"{where}: 'format' must be {FORMAT}, got {fmt!r}")
    unknown = set(data) - {
        "format",
        "event",
        "description",
        "pack",
        "scene",
        "dt",
        "steps",
        "digest",
        "settings",
        "chainsim",
    }
    if unknown:
        raise UserError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}; expected format, event, description")
    raw = data.get("event", [])
    if not isinstance(raw, list):
        raise UserError(f"{where}: 'event' must be an array of tables ([[event]])")
    if len(raw) > limits.MAX_EVENTS:
        raise UserError(f"{where}: {len(raw):,} events, over the {limits.MAX_EVENTS:,} limit (docs/limits.md)")
    out = []
    last = 0.0
    for i, item in enumerate(raw):
        w = f"{where}: event {i + 1}"
        if not isinstance(item, dict):
            raise UserError(f"{w}: must be a table")
        t = item.get("t")
        if (
            isinstance(t, bool)
            or not isinstance(t, (int, float))
            or not (isinstance(t, int) or math.isfinite(t))
            or not 0 <= t <= limits.MAX_TIME
        ):
            shown = repr(t) if not isinstance(t, int) or len(str(t)) < 25 else f"a {len(str(t))}-digit number"
            raise UserError(f"{w}: 't' must be a number of seconds from 0 to {limits.MAX_TIME:g}, got {shown}")
        if t < last:
            raise UserError(f"{w}: events must be in time order (t={t} after t={last})")
        last = float(t)
        out.append((float(t), event_from_dict(item, w)))
    return out


def read_file(path: str | Path) -> dict:
    """An input script or recording (.toml as TOML, anything else as JSON), within the data limits."""
    return datafile.load(path, max_bytes=limits.MAX_SCRIPT_BYTES, what="input file")


def load_script(path: str | Path) -> list[tuple[float, Any]]:
    return parse_events(read_file(path), str(path))


def write_recording(
    path: str | Path, *, pack: str, scene: str, dt: float, steps: int, events, digest: str, settings: dict | None = None
) -> None:
    """Write atomically (temp file + rename): an interrupted write never clobbers an old recording."""
    data = {
        "chainsim": "recording",
        "format": FORMAT,
        "pack": pack,
        "scene": scene,
        "dt": dt,
        "steps": steps,
        # where attempts were saved is the recorder's own business: a replay never saves
        "settings": {k: v for k, v in (settings or {}).items() if k not in ("db", "records")},
        "digest": digest,
        "event": [dict(t=t, **event_to_dict(ev)) for t, ev in events],
    }
    write_text_atomic(path, json.dumps(data, indent=1, allow_nan=False), "--record")

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

Both are read through chainsim.systems.engine.datafile (size, nesting and number limits) and every event
is checked (times finite, in order and at most MAX_TIME; at most MAX_EVENTS events).
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

from chainsim.components.input_events import event_from_dict, event_to_dict
from chainsim.game.common.outputs import write_text_atomic
from chainsim.systems.engine import datafile, limits
from chainsim.systems.engine.errors import UserError

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
        "protocol",  # a study trial's recording names its trial (chainsim.game.study.protocol)
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
    """An input script or recording (.toml as TOML, anything else as JSON), within the data limits.

    A number the reader refuses (NaN or Infinity in JSON, an integer past 64 bits, a float that
    overflows) is named by its event and key, as docs/input-scripts.md promises: `event 3: 'value' ...`.
    """
    text = datafile.read_text(path, max_bytes=limits.MAX_SCRIPT_BYTES, what="input file")
    toml = Path(path).suffix.lower() == ".toml"
    try:
        return datafile.parse_toml(text, str(path)) if toml else datafile.parse_json(text, str(path))
    except datafile.DataError as e:
        key, detail = (e.key, e.detail) if e.key or toml else _bad_json_number(text)
        m = re.fullmatch(r"integer of (\d+) digits is out of the 64-bit range", detail)
        detail = f"is a {m.group(1)}-digit integer, out of the 64-bit range" if m else detail
        if not key or e.line is not None:
            raise
        raise UserError(f"{path}: {_key_place(key)} {detail}") from None


class _BadNumber:
    """A number the strict JSON reader refuses, kept (by the second, lenient reading) to find its key."""

    def __init__(self, detail: str):
        self.detail = detail


def _lenient_int(s: str):
    digits = len(s.lstrip("-"))
    return (
        _BadNumber(f"is a {digits}-digit integer, out of the 64-bit range")
        if digits > 18 and not (-(2**63) <= int(s) < 2**63)
        else int(s)
    )


def _lenient_float(s: str):
    x = float(s)
    return x if math.isfinite(x) else _BadNumber(f"is {s[:30]}, too large for a float")


def _bad_json_number(text: str) -> tuple[str, str]:
    """(dotted key, what is wrong) of the first number strict JSON reading refused; ("", "") if none.
    Only called after the strict reading passed its nesting check, so this reading is bounded too."""
    try:
        data = json.loads(
            text,
            parse_int=_lenient_int,
            parse_float=_lenient_float,
            parse_constant=lambda s: _BadNumber(f"must be a finite number, got {s}"),
        )
    except (ValueError, RecursionError):
        return "", ""
    stack: list[tuple[Any, str]] = [(data, "")]
    while stack:  # depth first, in the file's order
        v, key = stack.pop()
        if isinstance(v, _BadNumber):
            return key, v.detail
        items = v.items() if isinstance(v, dict) else enumerate(v) if isinstance(v, list) else ()
        stack.extend(reversed([(x, f"{key}.{k}" if key else str(k)) for k, x in items]))
    return "", ""


def _key_place(key: str) -> str:
    """'event.2.point.1' -> "event 3: 'point'"; any other key -> "'key'"."""
    parts = key.split(".")
    if len(parts) >= 3 and parts[0] == "event" and parts[1].isdigit():
        return f"event {int(parts[1]) + 1}: '{parts[2]}'"
    return f"'{key}'"


def load_script(path: str | Path) -> list[tuple[float, Any]]:
    return parse_events(read_file(path), str(path))


def write_recording(path: str | Path, **fields) -> None:
    """Write atomically (temp file + rename): an interrupted write never clobbers an old recording."""
    write_text_atomic(path, json.dumps(recording_data(**fields), indent=1, allow_nan=False), "--record")


def recording_data(
    *, pack: str, scene: str, dt: float, steps: int, events, digest: str, settings: dict | None = None
) -> dict:
    """A recording as a JSON-ready dict (what `--record` writes and what an upload to a records server carries)."""
    return {
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

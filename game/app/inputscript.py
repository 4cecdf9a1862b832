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
"""

from __future__ import annotations

import json
import math
import os
import tomllib
from pathlib import Path
from typing import Any

from chainsim.components.input_events import event_from_dict, event_to_dict
from chainsim.engine.errors import UserError

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
    out = []
    last = 0.0
    for i, item in enumerate(raw):
        w = f"{where}: event {i + 1}"
        if not isinstance(item, dict):
            raise UserError(f"{w}: must be a table")
        t = item.get("t")
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0:
            raise UserError(f"{w}: 't' must be a finite number of seconds >= 0, got {t!r}")
        if t < last:
            raise UserError(f"{w}: events must be in time order (t={t} after t={last})")
        last = float(t)
        out.append((float(t), event_from_dict(item, w)))
    return out


def read_file(path: str | Path) -> dict:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"{path}: input file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise UserError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    if path.suffix.lower() == ".toml":
        try:
            return tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise UserError(f"{path}: TOML syntax error: {e}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise UserError(f"{path}: JSON syntax error at line {e.lineno}: {e.msg}") from None


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
        "settings": settings or {},
        "digest": digest,
        "event": [dict(t=t, **event_to_dict(ev)) for t, ev in events],
    }
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1), encoding="utf-8")
    os.replace(tmp, path)

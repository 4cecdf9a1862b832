"""Input events: the one vocabulary shared by the window, input scripts, recordings and widgets.

A real window, a scripted run and a replay all produce these same events, so a test can press a
widget or click the face exactly as a trainee does. Window coordinates are pixels with the origin at
the bottom-left (pyglet's convention). `kind` is the name used in input scripts (see
docs/input-scripts.md). Numbers read from a script are finite and bounded (chainsim.systems.engine.limits:
coordinates within MAX_COORD, sizes within MAX_PIXELS), names within MAX_KEY_LENGTH characters.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, asdict, dataclass, fields
from typing import Any, ClassVar

from chainsim.systems.engine import limits
from chainsim.systems.engine.errors import UserError


@dataclass(frozen=True, slots=True)
class MouseMove:
    kind: ClassVar[str] = "mouse_move"
    x: float
    y: float


@dataclass(frozen=True, slots=True)
class MouseButton:
    """A press or release; a click is a press followed by a release."""

    kind: ClassVar[str] = "mouse_button"
    x: float
    y: float
    button: str = "left"
    pressed: bool = True


@dataclass(frozen=True, slots=True)
class MouseDrag:
    kind: ClassVar[str] = "mouse_drag"
    x: float
    y: float
    dx: float
    dy: float
    button: str = "left"


@dataclass(frozen=True, slots=True)
class Scroll:
    kind: ClassVar[str] = "scroll"
    x: float
    y: float
    dy: float


@dataclass(frozen=True, slots=True)
class Key:
    kind: ClassVar[str] = "key"
    key: str
    pressed: bool = True


@dataclass(frozen=True, slots=True)
class Widget:
    """A control-panel action: a button press (value None), a toggle (bool) or a dial/slider (float)."""

    kind: ClassVar[str] = "widget"
    name: str
    value: Any = None


@dataclass(frozen=True, slots=True)
class Resize:
    kind: ClassVar[str] = "resize"
    width: int
    height: int


@dataclass(frozen=True, slots=True)
class PickPoint:
    """Pick a world point on a named entity directly (scripts that must not depend on the camera)."""

    kind: ClassVar[str] = "pick"
    entity: str
    point: tuple[float, float, float]
    button: str = "left"


EVENT_TYPES: dict[str, type] = {
    cls.kind: cls for cls in (MouseMove, MouseButton, MouseDrag, Scroll, Key, Widget, Resize, PickPoint)
}

_BUTTONS = {"left", "middle", "right"}


def event_to_dict(event) -> dict[str, Any]:
    d = {"kind": event.kind}
    d.update(asdict(event))
    if "point" in d:
        d["point"] = list(d["point"])
    return d


def _number(where: str, key: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UserError(f"{where}: '{key}' must be a number, got {value!r}"[:300])
    if isinstance(value, float) and not math.isfinite(value):
        raise UserError(f"{where}: '{key}' must be finite, got {value!r}")
    try:
        return limits.number(value)
    except limits.LimitError as e:
        raise UserError(f"{where}: '{key}' {e} (docs/limits.md)") from None


def event_from_dict(d: dict[str, Any], where: str):
    """Build an event from a script table; `where` names the file and entry for error messages."""
    if not isinstance(d, dict):
        raise UserError(f"{where}: each event must be a table, got {type(d).__name__}")
    kind = d.get("kind")
    cls = EVENT_TYPES.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise UserError(f"{where}: unknown event kind {kind!r}; expected one of {', '.join(sorted(EVENT_TYPES))}")
    allowed = {f.name for f in fields(cls)}
    extra = set(d) - allowed - {"kind", "t"}
    if extra:
        raise UserError(
            f"{where}: unknown key(s) {', '.join(sorted(extra))} for a '{kind}' event; "
            f"expected {', '.join(sorted(allowed))}"
        )
    args = {}
    for f in fields(cls):
        if f.name not in d:
            if f.default is not MISSING:
                continue
            raise UserError(f"{where}: '{kind}' event needs '{f.name}'")
        v = d[f.name]
        if f.name in ("x", "y", "dx", "dy"):
            v = _number(where, f.name, v)
        elif f.name in ("width", "height"):
            if isinstance(v, bool) or not isinstance(v, int) or not 0 < v <= limits.MAX_PIXELS:
                raise UserError(f"{where}: '{f.name}' must be a whole number from 1 to {limits.MAX_PIXELS}, got {v!r}")
        elif f.name == "pressed":
            if not isinstance(v, bool):
                raise UserError(f"{where}: 'pressed' must be true or false, got {v!r}")
        elif f.name == "button":
            if v not in _BUTTONS:
                raise UserError(f"{where}: 'button' must be one of left, middle, right; got {v!r}")
        elif f.name in ("key", "name", "entity"):
            if not isinstance(v, str) or not v or len(v) > limits.MAX_KEY_LENGTH:
                raise UserError(
                    f"{where}: '{f.name}' must be text of 1 to {limits.MAX_KEY_LENGTH} characters, got {v!r}"[:300]
                )
        elif f.name == "point":
            if not isinstance(v, (list, tuple)) or len(v) != 3:
                raise UserError(f"{where}: 'point' must be [x, y, z], got {v!r}")
            v = tuple(_number(where, "point", c) for c in v)
        elif f.name == "value":
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                v = _number(where, "value", v)
            elif isinstance(v, str) and len(v) > limits.MAX_TEXT_LENGTH:
                raise UserError(f"{where}: 'value' text is over {limits.MAX_TEXT_LENGTH} characters")
            elif v is not None and not isinstance(v, (bool, str)):
                raise UserError(f"{where}: 'value' must be a number, true/false or a string, got {v!r}"[:300])
        args[f.name] = v
    return cls(**args)

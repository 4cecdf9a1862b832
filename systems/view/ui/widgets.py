"""The control panel without GL: widget placement, hit testing and value changes (thesis 3.3.4, the
controller that gathers the needle widgets, visibility switches and red/green feedback lights).

A widget is a layout table (see `chainsim docs components`, 'widget'). Using one - a click, a drag or
its keyboard shortcut - produces the value that the `Widget(name, value)` input event carries:

    button        None on click; `key_value` on its key when that is non-zero (e.g. -5 / +5 for two
                  buttons stepping one dial), else None
    toggle        the new state, true or false
    slider, dial  the new number, clamped to [min, max]; a key press moves it by `key_value`
                  (or `step`, or a twentieth of the range when both are 0)
    light, text   display only (lights show HudState.lights[name]; text shows its label and value)

`WidgetState` holds the current values; a scripted Widget event and a click change it through the same
`apply_widget` function, so they have the same effect. Names in `disabled` ignore clicks, keys and
scripted events (procedures fill it, e.g. to lock needle rotation once insertion starts).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from chainsim.systems.view.ui.viewports import Rect

INTERACTIVE = ("button", "toggle", "slider", "dial")
TITLE_PX = 26  # panel caption height
MARGIN_PX = 8
ROW_PX = {"button": 30, "toggle": 28, "slider": 42, "dial": 42, "light": 26, "text": 22}


@dataclass(slots=True)
class WidgetState:
    """Current widget values (resource). Procedures may read `values` and edit `disabled`."""

    specs: dict[str, dict] = field(default_factory=dict)  # name -> first widget table with that name
    values: dict[str, Any] = field(default_factory=dict)
    presses: dict[str, int] = field(default_factory=dict)  # button name -> times used
    disabled: set[str] = field(default_factory=set)

    @classmethod
    def from_layout(cls, widgets: list[dict]) -> WidgetState:
        st = cls()
        for w in widgets:
            st.specs.setdefault(w["name"], w)
            if w["name"] not in st.values:
                st.values[w["name"]] = initial_value(w)
        return st

    def get(self, name: str, default: Any = None) -> Any:
        return self.values.get(name, default)

    def set(self, name: str, value: Any) -> None:
        """Set a value from code (procedures); no event is emitted."""
        spec = self.specs.get(name)
        self.values[name] = normalise(spec, value, self.values.get(name)) if spec else value

    def enabled(self, name: str) -> bool:
        return name not in self.disabled

    def disable(self, *names: str) -> None:
        self.disabled.update(names)

    def enable(self, *names: str) -> None:
        self.disabled.difference_update(names)


def format_value(v: float) -> str:
    """The one number format of the interface (dials, sliders, text widgets): one decimal place."""
    t = f"{float(v):.1f}"
    return "0.0" if t == "-0.0" else t


def initial_value(w: dict) -> Any:
    kind, v = w["kind"], w.get("value", False)
    if kind == "toggle":
        return bool(v)
    if kind in ("slider", "dial"):
        try:
            x = float(v)
        except (TypeError, ValueError):
            x = float(w.get("min", 0.0))
        return _clamp(w, x)
    if kind == "button":
        return None
    return v


def _clamp(w: dict, x: float) -> float:
    lo, hi = float(w.get("min", 0.0)), float(w.get("max", 1.0))
    if lo > hi:
        lo, hi = hi, lo
    return min(max(float(x), lo), hi)


def normalise(w: dict, value: Any, current: Any) -> Any:
    """The value a widget holds after receiving `value` (None on a toggle flips it)."""
    kind = w["kind"]
    if kind == "toggle":
        return (not bool(current)) if value is None else bool(value)
    if kind in ("slider", "dial"):
        if value is None or isinstance(value, (bool, str)):
            return current
        return _clamp(w, float(value))
    return value


def apply_widget(state: WidgetState, name: str, value: Any) -> bool:
    """Apply a Widget(name, value) event to the state; False when the widget is disabled."""
    if name in state.disabled:
        return False
    spec = state.specs.get(name)
    if spec is None:
        state.values[name] = value
        return True
    if spec["kind"] == "button":
        state.presses[name] = state.presses.get(name, 0) + 1
    state.values[name] = normalise(spec, value, state.values.get(name))
    return True


def _key_step(w: dict) -> float:
    if w.get("key_value"):
        return float(w["key_value"])
    if w.get("step"):
        return float(w["step"])
    return (float(w.get("max", 1.0)) - float(w.get("min", 0.0))) / 20.0


def stepped(w: dict, current: Any, steps: int) -> float:
    """A slider/dial value moved by `steps` steps (`step`, or a twentieth of the range), clamped."""
    size = float(w.get("step") or 0.0) or (float(w.get("max", 1.0)) - float(w.get("min", 0.0))) / 20.0
    base = (
        float(current)
        if isinstance(current, (int, float)) and not isinstance(current, bool)
        else float(w.get("min", 0.0))
    )
    return _clamp(w, base + steps * size)


def key_value(w: dict, current: Any) -> Any:
    """The event value when the widget's shortcut key is pressed."""
    kind = w["kind"]
    if kind == "button":
        return float(w["key_value"]) if w.get("key_value") else None
    if kind == "toggle":
        return not bool(current)
    if kind in ("slider", "dial"):
        return _clamp(w, float(current if current is not None else w.get("min", 0.0)) + _key_step(w))
    return current


# -- placement -----------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Placed:
    """A widget table with its pixel rectangle (window pixels)."""

    spec: dict
    rect: Rect


def panel_widgets(widgets: list[dict], panel: str, first_panel: str) -> list[dict]:
    return [w for w in widgets if (w.get("viewport") or first_panel) == panel]


def place(widgets: list[dict], rect: Rect) -> list[Placed]:
    """Pixel rectangles of one panel's widgets: explicit fractions of the panel, or an automatic column
    under the caption (top to bottom, in table order)."""
    out = []
    y_top = rect.y + rect.h - TITLE_PX - MARGIN_PX
    width = max(rect.w - 2 * MARGIN_PX, 1)
    for w in widgets:
        fr = w.get("rect")
        if fr is not None and len(fr) == 4 and float(fr[2]) > 0 and float(fr[3]) > 0:
            x0 = rect.x + round(float(fr[0]) * rect.w)
            y0 = rect.y + round(float(fr[1]) * rect.h)
            r = Rect(x0, y0, round(float(fr[2]) * rect.w), round(float(fr[3]) * rect.h))
        else:
            h = ROW_PX.get(w["kind"], 28)
            r = Rect(rect.x + MARGIN_PX, y_top - h, width, h)
            y_top -= h + MARGIN_PX
        out.append(Placed(w, r))
    return out


def below_widgets(placed: list[Placed], rect: Rect) -> int:
    """Top pixel row free for text under the automatically placed widgets of a panel."""
    if not placed:
        return rect.y + rect.h - TITLE_PX - MARGIN_PX
    return min(p.rect.y for p in placed) - MARGIN_PX


def hit(placed: list[Placed], x: float, y: float) -> Placed | None:
    """The interactive widget under the point, if any (later widgets win where rectangles overlap)."""
    for p in reversed(placed):
        if p.spec["kind"] in INTERACTIVE and p.rect.contains(x, y):
            return p
    return None


def track(p: Placed) -> tuple[float, float]:
    """Left and right pixel x of a slider's track (the value maps linearly along it)."""
    pad = 10.0
    return p.rect.x + pad, p.rect.x + p.rect.w - pad


def slider_value(p: Placed, x: float) -> float:
    x0, x1 = track(p)
    t = min(max((x - x0) / max(x1 - x0, 1.0), 0.0), 1.0)
    lo, hi = float(p.spec.get("min", 0.0)), float(p.spec.get("max", 1.0))
    v = lo + t * (hi - lo)
    step = float(p.spec.get("step", 0.0))
    if step > 0:
        v = lo + round((v - lo) / step) * step
    return _clamp(p.spec, v)


def click_value(p: Placed, x: float, current: Any) -> Any:
    """The event value of a click at window x on widget `p`."""
    kind = p.spec["kind"]
    if kind == "button":
        return None
    if kind == "toggle":
        return not bool(current)
    if kind == "slider":
        return slider_value(p, x)
    if kind == "dial":  # left half turns down, right half turns up, one step per click
        step = (
            float(p.spec.get("step") or 0.0) or (float(p.spec.get("max", 1.0)) - float(p.spec.get("min", 0.0))) / 20.0
        )
        sign = -1.0 if x < p.rect.x + p.rect.w / 2 else 1.0
        return _clamp(p.spec, float(current) + sign * step)
    return current


def drag_value(p: Placed, x: float, dx: float, current: Any) -> Any:
    """The value while dragging on a slider (follows the cursor) or a dial (turns with dx)."""
    kind = p.spec["kind"]
    if kind == "slider":
        return slider_value(p, x)
    if kind == "dial":
        span = float(p.spec.get("max", 1.0)) - float(p.spec.get("min", 0.0))
        return _clamp(p.spec, float(current) + dx * span / max(p.rect.w, 1))
    return current

"""What the needle-procedure systems share: the entity ids they act on, the HUD, and the pack's feedback."""

from __future__ import annotations

from chainsim.components.app import App
from chainsim.components.hud import HudState


def hud(app: App):
    """The HUD resource (the view plugin's); one is made when running without it."""
    h = app.get_resource(HudState)
    if h is None:
        h = app.insert_resource(HudState())
    return h


class NeedleHandles:
    """Entity ids the procedure systems use (resource)."""

    def __init__(self, needle: int, procedure: int, markers: list, planes: list, labels: list):
        self.needle = needle
        self.procedure = procedure
        self.markers = markers
        self.planes = planes
        self.labels = labels  # the markers' label texts, shown once a landmark is placed


class _Blank(dict):
    def __missing__(self, key):
        return "{" + key + "}"


class Feedback:
    """The pack's [[feedback]] by event (resource): messages, lights and their colours."""

    def __init__(self, entries: list[dict], lights: list[str]):
        self.by_event: dict[str, list[dict]] = {}
        for e in entries:
            self.by_event.setdefault(e["on"], []).append(e)
        self.lights = list(lights)
        for e in entries:
            if e.get("light") and e["light"] not in self.lights:
                self.lights.append(e["light"])

    def has(self, event: str) -> bool:
        return event in self.by_event

    def light(self, event: str, lights: dict) -> None:
        """Set the lights the pack gives `event`, without its messages."""
        for e in self.by_event.get(event, []):
            if e.get("light") and e.get("color"):
                for name in lights:
                    lights[name] = "off"
                lights[e["light"]] = e["color"]

    def fire(self, app: App, event: str, lights: dict, default: str = "", **values) -> bool:
        """Show the event's messages and set its lights; `default` is said when the pack says nothing.
        Returns whether the pack declared feedback for the event."""
        entries = self.by_event.get(event, [])
        h = hud(app)
        said = False
        self.light(event, lights)
        for e in entries:
            if e.get("message"):
                h.message(e["message"].format_map(_Blank(values)))
                said = True
        if not said and default:
            h.message(default.format_map(_Blank(values)))
        return bool(entries)

"""What the HUD shows: the current procedure step, timed messages, indicator lights, panel text.

Procedures write `HudState` (a resource the view plugin inserts); the renderer only draws it, so a
headless run keeps the same state. Lights are the controller's red/green feedback (thesis 3.3.4): a
`light` widget named N shows `lights[N]`; lights without a widget are drawn in a row in the panel.
"""

from __future__ import annotations

from dataclasses import dataclass, field

LIGHT_STATES = ("red", "green", "off")


@dataclass(slots=True)
class HudState:
    step_title: str = ""
    step_instruction: str = ""
    messages: list[tuple[str, float | None]] = field(default_factory=list)  # (text, seconds left or None)
    lights: dict[str, str] = field(default_factory=dict)  # name -> "red" | "green" | "off"
    panel_text: list[str] = field(default_factory=list)  # e.g. self-assessment lines under the widgets
    # the pack's docs page reader: procedures name the page for the current step, the `help` widget
    # (or a `docs:NAME` button) opens and closes it, page keys scroll it
    doc_name: str = ""
    doc_open: bool = False
    doc_scroll: int = 0

    def open_doc(self, name: str | None = None) -> None:
        if name:
            self.doc_name = name
        self.doc_open = bool(self.doc_name)
        self.doc_scroll = 0

    def close_doc(self) -> None:
        self.doc_open = False

    def message(self, text: str, seconds: float | None = 4.0) -> None:
        """Show `text` for `seconds` of simulated time (None: until removed)."""
        self.messages.append((text, seconds))

    def set_light(self, name: str, state: str) -> None:
        if state not in LIGHT_STATES:
            raise ValueError(f"light state must be one of {', '.join(LIGHT_STATES)}, got {state!r}")
        self.lights[name] = state

    def age(self, dt: float) -> None:
        """Count timed messages down and drop the expired ones."""
        kept = []
        for text, left in self.messages:
            if left is None:
                kept.append((text, None))
            elif left - dt > 0:
                kept.append((text, left - dt))
        self.messages = kept

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
    counts: dict[str, int] = field(default_factory=dict)  # text -> times said while shown (drawn as "x3")
    lights: dict[str, str] = field(default_factory=dict)  # name -> "red" | "green" | "off"
    panel_text: list[str] = field(default_factory=list)  # e.g. self-assessment lines under the widgets
    # the pack's docs page reader: procedures name the page for the current step, the `help` widget
    # (or a `docs:NAME` button) opens and closes it, page keys scroll it
    doc_name: str = ""
    step_doc: str = ""  # the current step's page: what Help opens when another page was shown last
    doc_open: bool = False
    doc_scroll: int = 0
    # aiming aid drawn over an attached view: the target's world position and a note ("34.2 mm")
    aim_view: str = ""
    aim_target: tuple | None = None
    aim_note: str = ""
    # the needle's force gauge, drawn over the aim view: (axial N, lateral N, full scale N, caption, pop
    # text shown briefly after a layer gives); () none
    force_gauge: tuple = ()
    # rows of the key overlay (F1) that no widget shows: (keys, what they do); procedures add theirs
    key_rows: list[tuple[str, str]] = field(default_factory=list)
    # one line along the bottom of the panel: who is signed in and where records are kept
    status: str = ""
    # a question or notice in the page box (quit with an unsaved attempt, preparing the model); "" none
    notice: str = ""
    # the attempt's debrief over the main view: (text, tone) rows, tone one of chainsim.systems.procedures.
    # needle.debrief's (head, pass, fail, note, advice, critical); and its lines over the last X-ray image
    debrief: list[tuple[str, str]] = field(default_factory=list)
    debrief_paths: list[tuple] = field(default_factory=list)  # (points (K, 3) world mm, RGBA)
    # with a force-feedback device: the force the hand felt, (depth mm, force N, events) points, drawn as a
    # chart above the debrief
    debrief_force: list[tuple] = field(default_factory=list)

    def open_doc(self, name: str | None = None) -> None:
        if name:
            self.doc_name = name
        elif self.step_doc:
            self.doc_name = self.step_doc
        self.doc_open = bool(self.doc_name)
        self.doc_scroll = 0

    def close_doc(self) -> None:
        self.doc_open = False

    def message(self, text: str, seconds: float | None = 4.0) -> None:
        """Show `text` for `seconds` of simulated time (None: until removed). Saying the same thing
        again while it is shown restarts its time and counts it, instead of adding another line."""
        for i, (t, left) in enumerate(self.messages):
            if t == text:
                del self.messages[i]
                self.messages.append((text, None if (seconds is None or left is None) else max(seconds, left)))
                self.counts[text] = self.counts.get(text, 1) + 1
                return
        self.messages.append((text, seconds))
        self.counts[text] = 1

    def set_light(self, name: str, state: str) -> None:
        if state not in LIGHT_STATES:
            raise ValueError(f"light state must be one of {', '.join(LIGHT_STATES)}, got {state!r}")
        self.lights[name] = state

    def age(self, dt: float) -> None:
        """Count timed messages down and drop the expired ones."""
        kept: list[tuple[str, float | None]] = []
        for text, left in self.messages:
            if left is None:
                kept.append((text, None))
            elif left - dt > 0:
                kept.append((text, left - dt))
        self.messages = kept
        if len(self.counts) != len(kept):
            shown = {t for t, _ in kept}
            self.counts = {t: n for t, n in self.counts.items() if t in shown}

    def shown_messages(self) -> list[str]:
        """The messages as drawn: a repeated one carries its count."""
        return [t if self.counts.get(t, 1) <= 1 else f"{t} (x{self.counts[t]})" for t, _ in self.messages]

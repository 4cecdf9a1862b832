"""Resources every App owns: injected time, input state, settings, the pending-input queue.

Resources are singletons keyed by type (`app.resource(Time)`). Time is advanced only by the App's
fixed-step loop, never read from a clock, so a run is a pure function of its pack and input script.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from chainsim.systems.engine.errors import UserError


@dataclass(slots=True)
class Time:
    """Simulated time. `sim_time` is tick * dt exactly (no accumulated rounding)."""

    dt: float = 1.0 / 120.0
    tick: int = 0  # fixed simulation steps done
    frame: int = 0  # frames (App.update calls) done
    frame_dt: float = 0.0  # simulated seconds the current frame advances
    accumulator: float = 0.0  # simulated seconds not yet consumed by fixed steps

    @property
    def sim_time(self) -> float:
        return self.tick * self.dt


@dataclass(slots=True)
class InputState:
    """What the input devices look like right now (window pixels, origin bottom-left)."""

    mouse: tuple[float, float] = (0.0, 0.0)
    buttons: set[str] = field(default_factory=set)  # "left", "middle", "right"
    keys: set[str] = field(default_factory=set)  # pyglet key names, lower case: "left", "space", "r"
    modifiers: set[str] = field(default_factory=set)
    window_size: tuple[int, int] = (1280, 800)


@dataclass(slots=True)
class Settings:
    """Named options from the pack, the command line and the user; read-only for systems."""

    values: dict[str, Any] = field(default_factory=dict)

    def get(self, key: str, default: Any = None) -> Any:
        return self.values.get(key, default)


@dataclass(slots=True)
class PendingInput:
    """Timestamped input events waiting for their time (from a script, a replay or the window).

    Each item is (t_seconds, event). The input system releases those with t <= the simulated time
    at the start of the frame, in order.
    """

    items: list[tuple[float, Any]] = field(default_factory=list)
    cursor: int = 0

    def push(self, t: float, event: Any) -> None:
        """Queue `event` for simulated time `t`, in time order behind everything due by then: a seat pushes
        a tapped key's release a step ahead, and another key tapped after it must not wait behind that
        release (it would land in the same step as its own release, and no step would see it down)."""
        at = bisect.bisect_right(self.items, t, lo=self.cursor, key=lambda te: te[0])
        self.items.insert(at, (t, event))

    def extend(self, timed_events: Iterable[tuple[float, Any]]) -> None:
        self.items.extend(timed_events)
        self.items.sort(key=lambda te: te[0])  # stable: same-time events keep script order

    def due(self, now: float) -> list[Any]:
        out: list[Any] = []
        while self.cursor < len(self.items) and self.items[self.cursor][0] <= now + 1e-12:
            out.append(self.items[self.cursor][1])
            self.cursor += 1
        return out

    @property
    def exhausted(self) -> bool:
        return self.cursor >= len(self.items)


@dataclass(slots=True)
class PackResource:
    """The loaded pack and the scene being run (`pack` is a chainsim.game.packs.pack.Pack)."""

    pack: Any
    scene: str
    scene_spec: dict[str, Any]

    @property
    def layout_name(self) -> str:
        return self.scene_spec.get("layout", "")

    @property
    def layout(self) -> dict[str, Any]:
        return self.pack.section("layouts").get(self.layout_name, {"viewports": [], "widgets": []})


@dataclass(slots=True)
class EntityIndex:
    """Entity ids by manifest name."""

    by_name: dict[str, int] = field(default_factory=dict)

    def __getitem__(self, name: str) -> int:
        return self.by_name[name]

    def get(self, name: str, default: int | None = None) -> int | None:
        return self.by_name.get(name, default)


@dataclass(slots=True)
class Assessment:
    """Procedure results for the summary: plugins fill `values` (JSON-serialisable).

    A replay's procedure may `defer` them instead: nothing in a frame reads them, only the code that
    runs an App between frames (summaries, the window), so a replay works them out when they are
    read - from the state of the last frame, exactly as that frame would have - not every frame."""

    _values: dict[str, Any] = field(default_factory=dict)
    _deferred: Callable[[], dict[str, Any]] | None = None

    @property
    def values(self) -> dict[str, Any]:
        if self._deferred is not None:
            self._values, self._deferred = self._deferred(), None
        return self._values

    @values.setter
    def values(self, v: dict[str, Any]) -> None:
        self._values, self._deferred = v, None

    def defer(self, compute: Callable[[], dict[str, Any]]) -> None:
        """`values` are `compute()`, called when they are first read (until they are set or deferred again)."""
        self._deferred = compute


@dataclass(slots=True)
class RunInfo:
    """How this App was started (front ends and procedures may read it)."""

    pack_name: str
    scene: str
    headless: bool
    render: bool
    out_dir: str | None = None
    screenshot_every: int = 0
    # a replay (a records server's scoring, `chainsim replay`, a headless run that saves nothing): the
    # systems skip work that only feeds a window - pictures, HUD text, hover - and never what the world
    # digest or an attempt's figures are made of (tests/unit/test_replay_mode.py)
    replay: bool = False


class SavedLocally(UserError):
    """A Records save that is kept on this computer but not yet where it goes (an unreachable
    records server); the message says why and how it will be sent."""


@dataclass(slots=True)
class Records:
    """Where attempts are kept, as the shell chose it (a local store or a records server).

    Procedures save and list attempts through this resource and never open a store themselves, so a
    replay can insert one that refuses to write. `save_attempt(class, trainee, record) -> id` raises
    UserError when the save did not happen (SavedLocally when it is queued on this computer);
    `list_attempts(class, trainee) -> rows`.
    """

    save_attempt: Callable[[str, str, dict], int]
    list_attempts: Callable[[str, str], list[dict]]
    where: str = ""  # shown to the trainee: the database file or server address
    # delete_attempt(class, trainee, id): a trainee deletes one of their own attempts; None where the
    # store does not allow it
    delete_attempt: Callable[[str, str, int], None] | None = None
    # why these Records never save (a replay, a protocol trial), or "": a Save then says so and is no
    # failure, since nothing was meant to be saved
    refuses: str = ""
    # filed_as(id) -> (class, trainee, number): whom a records server files a save under (the signed-in
    # account, whatever names were typed) and the attempt's number among theirs; None: the names given
    filed_as: Callable[[int], tuple[str, str, int | None] | None] | None = None


@dataclass(slots=True)
class RunOutputs:
    """Files a run writes into its --out folder beside summary.json: name -> a function giving the text
    (a procedure puts its own here, e.g. the needle's needle_trace.csv)."""

    files: dict = field(default_factory=dict)


@dataclass(slots=True)
class FailedSaves:
    """Saves the user asked for that did not happen, one message each.

    A procedure that cannot save (a bad records database, a full disk) shows the message in the
    window and appends it here; a headless run that ends with any ends with exit code 2, after
    writing its summary, so a save that did not happen is never a silent success.
    """

    messages: list[str] = field(default_factory=list)

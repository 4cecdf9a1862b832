"""What a procedure declares to the shell: one `Procedure` object per procedure, listed in the one table
(chainsim.systems.procedures.PROCEDURES).

The shell (records, server pages, exports, reports, the study screens, the renderer, the pack checks)
never imports a procedure's package: it takes the pack's procedure from the table and reads what the
object declares. A declaration is light to import: each callable that needs the procedure's systems
imports them when called (the type checker still follows it), so importing the table compiles no
kernel and starting the app pays only for the procedure a pack uses.

The declarations, each optional beyond the name and the plugin:

    plugin, check_event     install the procedure's systems on an App; refuse a scripted event before a run
    systems                 the module holding its systems (importing it registers its manifest tables)
    layout                  its attempt in the trainee records: metric columns, words, units, marks ...
    study                   the study it runs (tasks, how each is scored, the post-session ratings)
    attempt_record          the records-store attempt for its assessment's values
    manifest                its keys in the shell's [[steps]] and [metrics.NAME] tables, with their help
    viewport_kinds, xray    the extra viewport kinds it draws, and the X-ray view's current image
    pack_problems           its checks of a pack's tables (key, message)
    needs_steps             whether a pack must declare at least one [[steps]]
    stored_targets          (key, entity) of every entity an attempt may store as what it ended on
    replay                  the 3-D replay's reader of its scene, one frame at a time
    haptics                 attaching a force-feedback device to its instrument
    bench                   the scripted run the benchmarks drive
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from types import ModuleType
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    from chainsim.components.app import App


class Column(NamedTuple):
    """A figure every attempt of a procedure has: its name (the attempt dict's key), its words and units
    on pages, its header in the terminal's attempt list, and whether it is a count (a whole number)."""

    name: str
    words: str
    units: str
    short: str
    whole: bool = False


@dataclass(frozen=True)
class AttemptLayout:
    """A procedure's attempt in the trainee records: what it measures and how pages say it."""

    #: the figures every attempt has, in the order lists, exports and pages show them; the first is its time
    columns: tuple[Column, ...]
    #: the aids whose effect on performance is compared, as an attempt records them
    aids: tuple[str, ...] = ()
    #: the error of the points the trainee marks, and the instrument's error at its target (metric names)
    mark_error: str = ""
    target_error: str = ""
    #: what the instrument may end on that is not a target, and a target's form in words
    known_targets: frozenset[str] = frozenset({"none"})
    target_form: str = "an object's lower_snake_case name"
    #: details keys of the marked points and their ideal positions, and how the attempt page heads them
    marks: str = ""
    ideal_marks: str = ""
    marks_heading: str = ""
    marks_column: str = ""
    marks_note: str = ""
    #: details and assessment fields said in words on an attempt's page: field -> (words, units)
    field_words: dict[str, tuple[str, str]] = field(default_factory=dict)
    #: (words, value) lines saying what the instrument touched, from an attempt's details
    contact_facts: Callable[[dict], list[tuple[str, str]]] = lambda details: []


@dataclass(frozen=True)
class Study:
    """The study a procedure runs: its tasks, each scored by one attempt metric, and the ratings asked
    after a session."""

    #: task -> the metric that scores it; how each is scored and what a trial asks, in words
    task_metric: dict[str, str]
    task_scored: dict[str, str]
    task_does: dict[str, str]
    #: a trial that starts from the marks at their ideal points: the [points] name of mark k on a side
    ideal_point: str
    mark_count: int
    #: the post-session ratings (id, question), and the averages the published study reports
    ratings: tuple[tuple[str, str], ...]
    published_ratings: dict[str, float]


@dataclass(frozen=True)
class ManifestKeys:
    """What a procedure adds to the shell's manifest tables (chainsim.game.packs.declarations)."""

    #: the procedure in words, for `pack.procedure`'s help
    help: str = ""
    #: the events that complete a step, for `[[steps]] done_on`'s help
    done_on_help: str = ""
    #: further keys of [[steps]] and of [metrics.NAME] (chainsim.components.registry.Field)
    step_fields: tuple[Any, ...] = ()
    metric_fields: tuple[Any, ...] = ()


@dataclass(frozen=True)
class XrayImage:
    """The X-ray view's current image request: the source's camera, which image, and its status line."""

    camera: Any
    image_id: int
    live: bool
    attempt: int
    images: int
    status: str
    view: str
    azimuth_deg: float
    elevation_deg: float


@dataclass(frozen=True)
class ReplayFrame:
    """One step of a replayed attempt, as the 3-D replay keeps it: the attempt and its clock, the
    instrument's tip and direction (NaN when not placed), and a contact made this step (role, point,
    whether it reached the target) or None."""

    attempt: int
    t: float
    tip: Any
    direction: Any
    contact: tuple[str, Any, bool] | None


@dataclass(frozen=True)
class ReplayReader:
    """Reads a procedure's scene in a replaying App: the attempt being made, one frame, the instrument's
    length in mm."""

    attempt: Callable[[], int]
    frame: Callable[[], ReplayFrame]
    length_mm: float


@dataclass(frozen=True)
class Bench:
    """The scripted run the benchmarks drive: the events of a straight insertion along a pack's path
    (events, depth, when it gets there), the deformable bodies it meets, and its trace's rows."""

    insertion: Callable[[Any, dict], tuple[list, float, float]]
    bodies: Callable[[App], list]
    trace_rows: Callable[[App], list]


@dataclass(frozen=True)
class Procedure:
    """One procedure, as the shell knows it (module docstring)."""

    name: str
    plugin: Callable[[App], None]
    systems: Callable[[], ModuleType]
    check_event: Callable[[Any], None] | None = None
    layout: AttemptLayout | None = None
    study: Study | None = None
    attempt_record: Callable[[str, dict], dict] | None = None
    manifest: ManifestKeys = ManifestKeys()
    viewport_kinds: tuple[str, ...] = ()
    xray: Callable[[App], XrayImage | None] | None = None
    pack_problems: Callable[[dict], list[tuple[str, str]]] | None = None
    #: whether a pack must declare at least one [[steps]] (the needle procedure moves through them)
    needs_steps: bool = False
    stored_targets: Callable[[dict], list[tuple[str, str]]] | None = None
    replay: Callable[[App], ReplayReader] | None = None
    haptics: Callable[..., Any] | None = None
    bench: Bench | None = None

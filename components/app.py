"""The App: one esper world, named stages in a fixed order, plugins, resources and the fixed-step loop.

Stages run in this order every frame (`App.update`):

    input       once per frame: turn device/script events into InputState and events
    simulation  0..n times per frame at a fixed dt (default 1/120 s): kinematics, collision,
                deformation, in that order (the ORDER_* constants)
    procedure   once per frame: procedure steps, assessment
    render      once per frame: drawing (absent in headless runs without a renderer)

Systems are callables `system(app)`; they talk through components, resources and events only.
A plugin is a function `build(app)` that inserts resources and adds systems. Each App owns its own
esper world, switched in before every system, so Apps (and tests) never share state.
"""

from __future__ import annotations

import itertools
import time as _wallclock  # profiling only: never feeds the simulation
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, TypeVar, overload

import esper

from chainsim.components.events import EventQueue
from chainsim.components.resources import InputState, PendingInput, Settings, Time
from chainsim.components.stages import STAGES

#: at most this many fixed steps per frame, so a stalled frame cannot spiral
MAX_STEPS_PER_FRAME = 32

_world_ids = itertools.count()

System = Callable[["App"], None]

T = TypeVar("T")


@dataclass(slots=True)
class SystemEntry:
    stage: str
    order: int
    seq: int
    name: str
    fn: System
    calls: int = 0
    total_s: float = 0.0
    max_s: float = 0.0


@dataclass(slots=True)
class Profile:
    """Wall-clock cost of each system, for summaries and benchmarks (never used by the simulation)."""

    enabled: bool = True
    entries: list[SystemEntry] = field(default_factory=list)


class App:
    """A simulation instance. See the module docstring for the stage order."""

    def __init__(self, *, dt: float = 1.0 / 120.0, settings: dict[str, Any] | None = None, name: str = "app"):
        if not (dt > 0 and dt < 1.0):
            raise ValueError(f"dt must be in (0, 1) seconds, got {dt!r}")
        self.world = f"chainsim-{name}-{next(_world_ids)}"
        self._resources: dict[type, Any] = {}
        self._systems: dict[str, list[SystemEntry]] = {s: [] for s in STAGES}
        self._seq = itertools.count()
        self._closers: list[Callable[[], None]] = []
        self.profile = Profile()
        self.events = EventQueue()
        self.time = Time(dt=dt)
        self.insert_resource(self.time)
        self.insert_resource(self.events)
        self.insert_resource(InputState())
        self.insert_resource(Settings(dict(settings or {})))
        self.insert_resource(PendingInput())
        self.closed = False

    # -- resources -------------------------------------------------------------------------
    # Resources are keyed by type, so each accessor returns the type it was asked for: mypy then checks
    # every `app.resource(Time).tick` in the systems against the resource's own class.
    def insert_resource(self, value: T, kind: type[T] | None = None) -> T:
        """Store `value` as the resource of its type (or `kind`); replaces any previous one."""
        self._resources[kind or type(value)] = value
        return value

    def resource(self, kind: type[T]) -> T:
        """The resource of type `kind`; KeyError (naming the type) when this App has none."""
        try:
            return self._resources[kind]
        except KeyError:
            raise KeyError(f"no resource of type {kind.__name__} in this App") from None

    @overload
    def get_resource(self, kind: type[T]) -> T | None: ...
    @overload
    def get_resource(self, kind: type[T], default: T) -> T: ...
    def get_resource(self, kind: type[T], default: T | None = None) -> T | None:
        """The resource of type `kind`, or `default` when this App has none."""
        return self._resources.get(kind, default)

    def has_resource(self, kind: type) -> bool:
        return kind in self._resources

    # -- systems and plugins -----------------------------------------------------------------
    def add_system(self, stage: str, fn: System, *, order: int = 0, name: str | None = None) -> None:
        if stage not in self._systems:
            raise ValueError(f"unknown stage {stage!r}; stages are {', '.join(STAGES)}")
        label = name or str(getattr(fn, "__name__", repr(fn)))
        entry = SystemEntry(stage, order, next(self._seq), label, fn)
        lst = self._systems[stage]
        lst.append(entry)
        lst.sort(key=lambda e: (e.order, e.seq))
        self.profile.entries.append(entry)

    def add_plugin(self, build: Callable[[App], None]) -> App:
        build(self)
        return self

    def on_close(self, fn: Callable[[], None]) -> None:
        self._closers.append(fn)

    def systems(self, stage: str) -> list[str]:
        return [e.name for e in self._systems[stage]]

    # -- the world ---------------------------------------------------------------------------
    @contextmanager
    def active(self) -> Iterator[None]:
        """Make this App's world esper's current world (for code outside systems, e.g. loaders, tests)."""
        previous = esper.current_world
        esper.switch_world(self.world)
        try:
            yield
        finally:
            esper.switch_world(previous)

    # -- the loop ----------------------------------------------------------------------------
    def _run_stage(self, stage: str) -> None:
        for entry in self._systems[stage]:
            if self.profile.enabled:
                t0 = _wallclock.perf_counter()
                entry.fn(self)
                dt = _wallclock.perf_counter() - t0
                entry.calls += 1
                entry.total_s += dt
                if dt > entry.max_s:
                    entry.max_s = dt
            else:
                entry.fn(self)
        esper.clear_dead_entities()

    def update(self, frame_dt: float | None = None) -> int:
        """Advance one frame of `frame_dt` simulated seconds (default: one fixed step).

        Returns the number of fixed simulation steps taken (0..MAX_STEPS_PER_FRAME).
        """
        if self.closed:
            raise RuntimeError("App is closed")
        t = self.time
        frame_dt = t.dt if frame_dt is None else float(frame_dt)
        if not (frame_dt >= 0.0):
            raise ValueError(f"frame_dt must be >= 0, got {frame_dt!r}")
        t.frame_dt = frame_dt
        self.events.begin_frame(t.frame)
        previous = esper.current_world
        esper.switch_world(self.world)
        try:
            self._run_stage("input")
            t.accumulator += frame_dt
            steps = 0
            # a tolerance keeps frame_dt == dt from losing a step to rounding
            while t.accumulator >= t.dt * (1.0 - 1e-9) and steps < MAX_STEPS_PER_FRAME:
                self._run_stage("simulation")
                t.accumulator -= t.dt
                t.tick += 1
                steps += 1
            if steps == MAX_STEPS_PER_FRAME:
                t.accumulator = min(t.accumulator, t.dt)
            if abs(t.accumulator) < 1e-12:
                t.accumulator = 0.0
            self._run_stage("procedure")
            self._run_stage("render")
            t.frame += 1
        finally:
            esper.switch_world(previous)
        return steps

    def run_steps(self, steps: int) -> None:
        """Run `steps` frames of exactly one fixed step each (headless runs, tests)."""
        for _ in range(steps):
            self.update(self.time.dt)

    def system_stats(self) -> dict[str, dict[str, float]]:
        """Mean and max wall-clock milliseconds per call, per system ("stage/name")."""
        out: dict[str, dict[str, float]] = {}
        for e in self.profile.entries:
            key = f"{e.stage}/{e.name}"
            out[key] = {
                "calls": e.calls,
                "mean_ms": (e.total_s / e.calls * 1e3) if e.calls else 0.0,
                "max_ms": e.max_s * 1e3,
            }
        return out

    def close(self) -> None:
        if self.closed:
            return
        for fn in reversed(self._closers):
            fn()
        if esper.current_world == self.world:
            esper.switch_world("default")
        if self.world in esper._context_map:
            esper.delete_world(self.world)
        self.closed = True

    def __enter__(self) -> App:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

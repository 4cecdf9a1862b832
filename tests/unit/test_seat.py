"""The seat the window and the browser trainer share (chainsim.game.trainer.seat): while the scene's kernels
compile a person's input waits and then reaches the App in order, keys tapped within a step land a step apart,
and the scene stands still meanwhile."""

from __future__ import annotations

import time

from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.assets import ASSETS_DIR
from chainsim.components.input_events import Key, MouseMove
from chainsim.game.packs import pack as packs
from chainsim.game.trainer.headless import app_for_pack
from chainsim.game.trainer.seat import Seat
from chainsim.systems.motion.input import InputLog


class _Compiler:
    """A compiler on a first start that finishes when the test says."""

    def __init__(self, finished: bool = False):
        self.finished = finished
        self.started = time.perf_counter()
        self.hurried: list[str] | None = None
        self.done: list[str] = []
        self.failed: dict[str, str] = {}
        self.seconds = 0.0
        self.groups: list[str] = []

    def ready(self, names=None) -> bool:
        return self.finished

    def prefer(self, names) -> None:
        pass

    def hurry(self, names) -> None:
        self.hurried = list(names)


def _app():
    return app_for_pack(packs.load(ASSETS_DIR / "chainmail-demo"), None, headless=False, save="")


def _keys(app) -> list[tuple[int, str, bool]]:
    dt = app.time.dt
    return [(round(t / dt), ev.key, ev.pressed) for t, ev in app.resource(InputLog).items if isinstance(ev, Key)]


def test_input_given_while_compiling_waits_then_reaches_the_scene_in_order():
    app = _app()
    compiler = _Compiler()
    seat = Seat(app, compiler, log=lambda s: None)
    try:
        assert seat.waiting()
        start = app.time.tick
        for key in ("r", "t"):
            seat.give(Key(key, True))
            seat.give(Key(key, False))
        for _ in range(5):
            assert seat.advance(1 / 30) is None  # the scene stands still while its input waits
        assert app.time.tick == start and not _keys(app)
        assert seat.first_picture() is not None and compiler.hurried == seat.kernels.gate.needed
        assert seat.first_picture() is None  # once
        compiler.finished = True
        for _ in range(10):
            seat.advance(1 / 30)
        assert not seat.waiting() and app.time.tick > start
        got = _keys(app)
        assert [k for _, k, p in got if p] == ["r", "t"]  # the presses in the order given
        for key in ("r", "t"):  # a tap is held for a step: its release lands in a later step than its press
            (pressed, _), (released, _) = [(s, p) for s, k, p in got if k == key]
            assert released > pressed
    finally:
        app.close()


@settings(max_examples=15, deadline=None)
@given(st.lists(st.tuples(st.sampled_from("abc"), st.integers(0, 3)), min_size=1, max_size=8))
def test_taps_of_one_key_land_a_step_apart_whatever_the_frames(taps):
    """Taps (press and release in the same frame) given with 0-3 frames between them: every press of a key
    lands in a step of its own and its release in a later one, as a person sees them at the window or in a
    tab (another key's taps do not wait for them)."""
    app = _app()
    seat = Seat(app, _Compiler(finished=True), log=lambda s: None)
    try:
        for key, frames in taps:
            seat.give(Key(key, True))
            seat.give(Key(key, False))
            for _ in range(frames):
                seat.advance(app.time.dt)
        for _ in range(2 * len(taps) + 2):
            seat.advance(app.time.dt)
        got = _keys(app)
        for key in "abc":
            mine = [(s, p) for s, k, p in got if k == key]
            assert [p for _, p in mine] == [True, False] * sum(k == key for k, _ in taps)  # every tap seen
            for (s0, _), (s1, _) in zip(mine, mine[1:]):
                assert s1 > s0  # press, release, press ... each in a later step: every tap one turn
    finally:
        app.close()


def test_the_pointer_moves_until_something_is_held_then_waits_too():
    """A move goes to the scene while nothing waits; once a press is held, moves are held behind it, so a
    held click never lands where the pointer went later."""
    app = _app()
    seat = Seat(app, _Compiler(), log=lambda s: None)
    try:
        seat.give(MouseMove(10.0, 20.0))
        assert len(seat.pending.items) == 1
        seat.give(Key("r", True))
        seat.give(MouseMove(30.0, 40.0))
        assert len(seat.pending.items) == 1
    finally:
        app.close()

"""The needle trainer scores technique, not input: the prp pack driven as a trainee drives its window -
key presses and releases at a person's pace (0.1-0.3 s apart), the App stepped between them at its
fixed step - for bone contacts (one per place the needle meets the bone, however often it is pushed
there), refused rotations (turns asked for with the needle in, each said on the HUD; not the turns
asked for while the needle withdraws to the skin, which are made there), and input given while the
window's kernels compile (held and applied in order once they are ready, never dropped)."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import esper
import numpy as np
import pytest

from chainsim.components.hud import HudState
from chainsim.components.input_events import Key, MouseButton, PickPoint, Widget
from chainsim.components.resources import Assessment, PendingInput
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script
from chainsim.systems.motion.input import InputLog
from chainsim.systems.procedures.needle.collision import NeedleHit, new_contact
from chainsim.systems.procedures.needle.components import Needle, NeedleState, Touch
from chainsim.systems.procedures.needle.handles import NeedleHandles
from chainsim.systems.procedures.needle.kinematics import RotationRefused
from chainsim.systems.procedures.needle.procedure import DEFAULTS

ROOT = Path(__file__).resolve().parents[2]
SCRIPTS = ROOT / "assets" / "prp" / "scripts"
# skull-hit.toml's ideal landmarks and its aim, 12 degrees too high: the needle meets the skull base
LANDMARKS = [(-46.43098, 52.595976, -38.153995), (-28.499958, 58.719781, 13.499996), (-69.91824, 12.917006, -1.333049)]
AIM_AT_BONE = (-17.556006, 45.494059)
LOCKED = "The dials are locked while the needle is in"  # the start of prp's refused:locked message
HELD = DEFAULTS["turn_held"]
KEY_DOWN = 0.08  # how long a tapped key is held down


class Trainee:
    """The prp trainer, headless, given input as the window gives it: each event stamped with the
    simulated time it is given at, the App stepped in between."""

    def __init__(self):
        self.app = build_app("prp")
        self.app.events.log = []

    def wait(self, seconds: float) -> None:
        end = self.app.time.sim_time + seconds
        while self.app.time.sim_time < end - 1e-9:
            self.app.update(self.app.time.dt)

    def give(self, *events, gap: float = 0.25) -> None:
        for ev in events:
            self.app.resource(PendingInput).push(self.app.time.sim_time, ev)
            self.wait(gap)

    def tap(self, key: str, times: int = 1, gap: float = 0.2, shift: bool = False) -> None:
        """Press and release `key`, `times` times, a press every `gap` seconds (Shift held throughout)."""
        if shift:
            self.give(Key("lshift", True), gap=0.1)
        for _ in range(times):
            self.give(Key(key, True), gap=KEY_DOWN)
            self.give(Key(key, False), gap=gap - KEY_DOWN)
        if shift:
            self.give(Key("lshift", False), gap=0.1)

    def aim_at_bone(self) -> None:
        self.give(*(PickPoint("skin", p) for p in LANDMARKS))
        self.give(Widget("rotate_horizontal", AIM_AT_BONE[0]), Widget("rotate_vertical", AIM_AT_BONE[1]))

    @property
    def needle(self) -> NeedleState:
        with self.app.active():
            return esper.component_for_entity(self.app.resource(NeedleHandles).needle, NeedleState)

    @property
    def values(self) -> dict:
        return self.app.resource(Assessment).values

    @property
    def hud(self) -> HudState:
        return self.app.resource(HudState)

    def said(self, start: str) -> int:
        """How many times a message beginning with `start` was said while it stayed on the HUD."""
        return sum(self.hud.counts.get(t, 1) for t, _ in self.hud.messages if t.startswith(start))

    def hits(self) -> list[NeedleHit]:
        return [e for e in self.app.events.log if isinstance(e, NeedleHit)]

    def tap_in_until_bone(self, most: int = 20) -> None:
        """Tap `i` until the tip meets bone, as a trainee feels the way."""
        before = len(self.hits())
        for _ in range(most):
            self.tap("i")
            if len(self.hits()) > before:
                self.wait(0.3)  # the spring-back
                return
        raise AssertionError(f"no bone within {most} taps of i")


@pytest.fixture()
def trainee():
    t = Trainee()
    yield t
    t.app.close()


# -- bone contacts ----------------------------------------------------------------------------------


def test_tapping_i_against_the_bone_is_one_contact(trainee):
    trainee.aim_at_bone()
    trainee.give(Widget("insert", 50.0), gap=0.5)
    trainee.tap("i", times=20)
    hits = trainee.hits()
    # the tip met the bone again and again (each tap after the spring-back), all at one place
    assert len(hits) >= 5 and {h.role for h in hits} == {"skull"}
    assert [h.counted for h in hits] == [True] + [False] * (len(hits) - 1)
    assert trainee.values["skull_contacts"] == 1 and trainee.values["metrics"]["skull_contacts"] == 1.0
    assert trainee.values["lights"]["skull"] == "red"
    assert trainee.said("Still on the skull at the same place: one contact until you withdraw 2 mm") >= 1


def test_a_contact_counts_again_after_withdrawing_2_mm_past_the_spring_back(trainee):
    trainee.aim_at_bone()
    trainee.give(Widget("insert", 50.0), gap=0.5)
    trainee.tap_in_until_bone()
    assert trainee.values["skull_contacts"] == 1
    trainee.tap("o", times=2, shift=True)  # back 1 mm: still pushing on at the same place
    trainee.tap_in_until_bone()
    assert trainee.values["skull_contacts"] == 1
    trainee.tap("o")  # back 2 mm, then 1 more: 3 mm past where the spring-back left it
    trainee.tap("o", times=2, shift=True)
    trainee.tap_in_until_bone()
    assert trainee.values["skull_contacts"] == 2
    assert trainee.hits()[-1].counted


def test_redirecting_at_the_skin_makes_the_next_touch_a_new_contact(trainee):
    trainee.aim_at_bone()
    trainee.give(Widget("insert", 50.0), gap=0.5)
    trainee.tap_in_until_bone()
    trainee.give(Widget("insert", 0.0), gap=1.2)  # withdrawn to the skin
    trainee.tap("right", times=3)  # redirected 3 degrees
    trainee.give(Widget("insert", 50.0), gap=0.5)
    trainee.tap_in_until_bone()
    assert trainee.values["skull_contacts"] == 2 and trainee.values["redirections"] == 1


def _touched(shallowest: float) -> NeedleState:
    """A needle whose last skull contact was at (0, 0, 60) pointing along +Z, left at depth 50 by the
    spring-back, and withdrawn to `shallowest` since."""
    st = NeedleState()
    st.touches["skull"] = Touch(np.array([0.0, 0.0, 60.0]), np.array([0.0, 0.0, 1.0]), 50.0, shallowest)
    return st


@pytest.mark.parametrize(
    ("shallowest", "direction_deg", "point", "new"),
    [
        (50.0, 0.0, (0.0, 0.0, 60.0), False),  # pushed on in place
        (48.5, 0.0, (0.0, 0.0, 60.0), False),  # withdrawn 1.5 mm past the spring-back
        (48.0, 0.0, (0.0, 0.0, 60.0), True),  # withdrawn 2 mm
        (50.0, 1.0, (0.0, 0.0, 60.0), False),  # turned 1 degree
        (50.0, 2.0, (0.0, 0.0, 60.0), True),  # turned 2 degrees
        (50.0, 0.0, (1.5, 0.0, 60.0), False),  # 1.5 mm along the bone
        (50.0, 0.0, (2.0, 0.0, 60.0), True),  # 2 mm along the bone
    ],
)
def test_the_rule_for_a_new_contact(shallowest, direction_deg, point, new):
    st = _touched(shallowest=shallowest)
    a = math.radians(direction_deg)
    assert new_contact(Needle(), st, "skull", np.array(point), np.array([math.sin(a), 0.0, math.cos(a)])) is new
    assert new_contact(Needle(), st, "mandible_role", np.array(point), np.array([0.0, 0.0, 1.0]))  # a first


# -- refused rotations ------------------------------------------------------------------------------


def test_turns_with_the_needle_in_are_refused_and_said_each_time(trainee):
    trainee.aim_at_bone()
    trainee.give(Widget("insert", 20.0), gap=0.5)
    yaw = trainee.needle.yaw
    trainee.tap("right", times=5, gap=0.25)
    assert trainee.values["rotation_refused"] == 5 and trainee.values["metrics"]["rotation_refused"] == 5.0
    assert len([e for e in trainee.app.events.log if isinstance(e, RotationRefused)]) == 5
    assert trainee.said(LOCKED) == 5  # on the HUD as "... (x5)"
    assert trainee.needle.yaw == yaw


def test_turns_right_after_the_slider_goes_to_0_are_made_at_the_skin_not_refused(trainee):
    trainee.aim_at_bone()
    trainee.give(Widget("insert", 40.0), gap=0.8)
    yaw = trainee.needle.yaw
    trainee.give(Widget("insert", 0.0), gap=0.1)  # withdrawing at 60 mm/s: 0.67 s to the skin
    trainee.tap("right", times=3, gap=0.1)
    assert trainee.needle.depth > 0.0 and trainee.values["rotation_refused"] == 0
    assert trainee.said(HELD) == 3 and trainee.said(LOCKED) == 0
    trainee.wait(1.0)
    assert trainee.needle.depth == 0.0 and not trainee.needle.locked
    assert trainee.needle.yaw == pytest.approx(yaw + 3.0)  # the three turns, made at the skin
    assert trainee.values["rotation_refused"] == 0 and trainee.values["redirections"] == 1


def test_going_back_in_before_the_skin_drops_the_waiting_turns_and_says_so(trainee):
    trainee.aim_at_bone()
    trainee.give(Widget("insert", 40.0), gap=0.8)
    yaw = trainee.needle.yaw
    trainee.give(Widget("insert", 0.0), gap=0.1)
    trainee.tap("right", times=2, gap=0.1)
    trainee.tap("i")
    assert trainee.said("The needle went in again before it reached the skin: 2 turns") == 1
    trainee.wait(1.0)
    assert trainee.needle.yaw == yaw and trainee.values["rotation_refused"] == 0


# -- input while the kernels compile ----------------------------------------------------------------


class _Compiling:
    """The window's kernel compiler on a first start, finishing when the test says."""

    def __init__(self):
        self.done: list[str] = []
        self.failed: dict[str, str] = {}
        self.total = 4
        self.started = self.seconds = 0.0
        self.finished = False

    def ready(self, names=None) -> bool:
        return self.finished

    def prefer(self, names) -> None:
        pass

    def hurry(self, names) -> None:
        self.hurried = list(names)


class _WallClock:
    """The window's wall clock, moved by the test (frames of 1/60 s)."""

    def __init__(self):
        self.now = 100.0

    def perf_counter(self) -> float:
        return self.now


def test_a_burst_of_input_while_the_kernels_compile_waits_visibly_and_is_applied_in_order(monkeypatch):
    import chainsim.game.trainer.seat as seat
    import chainsim.game.trainer.window as window

    monkeypatch.setattr(window.render, "draw", lambda app: None)  # no GL here: the scene is what is tested
    clock = _WallClock()
    monkeypatch.setattr(window, "time", clock)
    monkeypatch.setattr(seat, "time", clock)  # the seat stamps held input with the same wall clock
    compiler = _Compiling()
    app = build_app("prp", settings={"class": "c", "trainee": "t"})
    try:
        args = SimpleNamespace(exit_after=None, frame_times=None)
        ui = window.WindowSession(app, None, None, compiler, args=args, settings={}, script=None)
        ui.begin(None)
        hud = app.resource(HudState)
        assert not hasattr(compiler, "hurried")  # before the first picture the children stay in the background
        ui.on_draw()
        assert compiler.hurried == ui.seat.kernels.gate.needed  # then the scene's own groups compile at normal priority

        def frames(seconds: float) -> None:
            for _ in range(round(seconds * 60)):
                clock.now += 1 / 60
                ui.on_draw()

        # the correct attempt's first clicks (close the reading page, the three landmarks), then 77 key
        # presses, 0.1 s apart, each released after 0.05 s: all given while the kernels compile
        given = [(t, ev) for t, ev in load_script(SCRIPTS / "correct-mouse.toml") if t < 1.9]
        burst = ["right"] * 40 + ["left"] * 37
        for k, name in enumerate(burst):
            given += [(2.0 + 0.1 * k, Key(name, True)), (2.05 + 0.1 * k, Key(name, False))]
        at = 0.0
        for t, ev in given:
            frames(t - at)
            at = t
            ui.send(ev)
        frames(0.5)
        log = app.resource(InputLog).items
        assert not any(isinstance(ev, Key) for _, ev in log)  # none has reached the scene yet ...
        assert not any(isinstance(ev, MouseButton) and ev.y == 319.0 for _, ev in log)
        waits = [t for t, _ in hud.messages if t.startswith("Your input waits")]
        assert waits and waits[0].startswith("Your input waits (80 presses and clicks)")  # ... and it says so

        compiler.finished = True
        frames(0.1)
        assert any(t.startswith("Ready: the 80 presses and clicks given while preparing") for t, _ in hud.messages)
        frames(10.0)  # the held input comes with its own spacing: 9.3 s from the first landmark click
        pressed = [ev.key for _, ev in log if isinstance(ev, Key) and ev.pressed]
        assert pressed == burst  # every press, in order
        with app.active():
            st = esper.component_for_entity(app.resource(NeedleHandles).needle, NeedleState)
        assert st.placed and st.yaw == pytest.approx(3.0)  # the landmarks placed the needle, the keys turned it
    finally:
        app.close()


def test_input_given_after_the_kernels_are_ready_waits_behind_what_was_held():
    from chainsim.game.trainer.compiling import KernelGate

    compiler = _Compiling()
    gate, hud = KernelGate(compiler, ["normals and collision"]), HudState()
    press, release = Key("lshift", True), Key("lshift", False)
    assert not gate.lets_through(press, hud, "")
    gate.hold(1.0, press)
    compiler.finished = True  # ready between two window events, before the next frame releases the held
    assert not gate.lets_through(release, hud, "")  # so Shift's release cannot overtake its press
    gate.hold(1.2, release)
    assert [ev for _, ev in gate.release(5.0, 0.1)] == [press, release]
    assert gate.lets_through(Key("i", True), hud, "")

"""`chainsim warmup` compiles (or loads) every kernel ahead and says when they are ready; afterwards
no built-in pack, played with its scripts and drawn as the window draws it, needs a kernel compiled
for an argument type warmup did not compile (the first forceps grip once waited 13.8 s on that)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.game.cli.main import main

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_warmup_command_readies_the_kernels(capsys):
    assert main(["-q", "warmup"]) == 0
    assert "kernels ready" in capsys.readouterr().out


def _signatures() -> dict[str, set[str]]:
    from numba.core.registry import CPUDispatcher

    out = {}
    for mod in list(sys.modules.values()):
        if getattr(mod, "__name__", "").startswith("chainsim"):
            for v in list(vars(mod).values()):
                if isinstance(v, CPUDispatcher):
                    out[f"{v.py_func.__module__}.{v.__name__}"] = {str(s) for s in v.signatures}
    return out


#: every built-in pack with scripts: each drags in its own ways (a pull held on out of reach searches
#: against the fixed elements' field, exact._pin_field, which warmup once left out)
SCRIPTED = sorted(p.parent.parent.name for p in (ROOT / "assets").glob("*/scripts/*.toml"))


@pytest.mark.slow
@pytest.mark.parametrize("pack", sorted(set(SCRIPTED)))
def test_no_pack_needs_a_kernel_type_warmup_left_out(pack, monkeypatch):
    monkeypatch.setenv("PYGLET_HEADLESS", "true")
    from chainsim.components.resources import PendingInput
    from chainsim.game.render.context import GLUnavailable
    from chainsim.game.render.render_system import draw
    from chainsim.game.trainer.headless import build_app
    from chainsim.game.trainer.inputscript import load_script

    main(["-q", "warmup"])
    before = _signatures()  # what warmup readied; anything else a run needs would compile mid-session
    for script in sorted((ROOT / "assets" / pack / "scripts").glob("*.toml"))[:2]:
        try:
            app = build_app(str(ROOT / "assets" / pack), render=True, headless=True, size=(640, 400))
        except GLUnavailable as e:
            pytest.skip(f"no EGL OpenGL 3.3 context: {e}")
        events = load_script(script)
        app.resource(PendingInput).extend(events)
        last = max(t for t, _ in events) + 0.2
        try:
            n = 0
            while app.time.sim_time < last:
                app.update(app.time.dt)
                n += 1
                if n % 15 == 0:
                    draw(app)
        finally:
            app.close()
        after = _signatures()
        missing = {k: v - before.get(k, set()) for k, v in after.items() if v - before.get(k, set())}
        assert not missing, f"{pack} {script.name} compiled during play: {missing}"


class _Compiling:
    """A stand-in for chainsim.systems.engine.warmup.Compiler whose groups finish when the test says so."""

    def __init__(self, total=7):
        self.done: list[str] = []
        self.failed: dict[str, str] = {}
        self.total = total
        self.started, self.seconds = 0.0, None

    def ready(self, names=None):
        return names is not None and all(n in self.done for n in names)

    def prefer(self, names):
        pass


def test_window_input_waits_for_the_kernels_and_then_arrives_in_order():
    from chainsim.components.hud import HudState
    from chainsim.components.input_events import Key, MouseButton, MouseMove
    from chainsim.game.trainer.compiling import KernelGate

    compiler = _Compiling()
    gate = KernelGate(compiler, ["normals and collision"])
    hud = HudState()
    assert gate.stepping() and not gate.ready()
    gate.show(hud)
    assert any("preparing the soft-tissue engine" in t and "0 of 1" in t for t, _ in hud.messages)
    # the help and the pointer need no kernel: they reach the App at once
    assert gate.lets_through(Key("f1", True), hud, "")
    assert gate.lets_through(MouseButton(5.0, 5.0, "left", True), hud, "help")
    assert gate.lets_through(MouseMove(1.0, 1.0), hud, "")
    # a click on the scene waits, and so does whatever follows it (its release)
    press, release = MouseButton(50.0, 60.0, "left", True), MouseButton(50.0, 60.0, "left", False)
    assert not gate.lets_through(press, hud, "")
    gate.hold(10.0, press)
    assert not gate.lets_through(Key("f1", True), hud, "")
    gate.hold(10.1, release)
    assert not gate.stepping()  # the scene stands still while input waits
    gate.show(hud)
    assert any(t.startswith("Your input waits") for t, _ in hud.messages)
    assert gate.release(3.0, 0.05) == []
    compiler.done.append("normals and collision")
    out = gate.release(3.0, 0.05)
    assert [ev for _, ev in out] == [press, release]
    assert out[0][0] == 3.0 and abs(out[1][0] - 3.1) < 1e-9  # the release comes as long after the press
    assert gate.stepping() and gate.lets_through(Key("r", True), hud, "")
    gate.show(hud)
    assert not any("soft-tissue engine" in t for t, _ in hud.messages)


@settings(max_examples=60, deadline=None)
@given(
    gaps=st.lists(st.floats(0.0, 0.4), min_size=2, max_size=30),
    ready_after=st.floats(0.0, 6.0),
    fps=st.sampled_from([20.0, 60.0, 144.0]),
)
def test_input_given_while_compiling_and_after_reaches_the_scene_in_order_with_its_spacing(gaps, ready_after, fps):
    """A seat's frames: input given while the kernels compile is held, input given while the held input is
    being replayed waits behind it, and every event reaches the scene in order, none closer to the one
    before it than it was given (less a frame): nothing arrives in a burst."""
    from chainsim.components.hud import HudState
    from chainsim.components.input_events import MouseButton
    from chainsim.components.resources import PendingInput
    from chainsim.game.trainer.compiling import KernelWatch

    compiler, hud, pending, dt = _Compiling(), HudState(), PendingInput(), 1 / 120
    watch = KernelWatch(compiler, ["normals and collision"], hud, pending, log=lambda s: None)
    given = []
    wall = 0.0
    for k, gap in enumerate(gaps):
        wall += gap
        given.append((wall, MouseButton(float(k), 0.0, "left", k % 2 == 0)))
    seen: list[tuple[float, object]] = []
    now, frame, i, t = 0.0, 1.0 / fps, 0, 0.0
    while len(seen) < len(given) and t < wall + ready_after + 60:
        t += frame
        if t >= ready_after:
            compiler.done = ["normals and collision"]
        while i < len(given) and given[i][0] <= t:
            if watch.lets_through(given[i][1], given[i][0]):
                pending.push(now, given[i][1])
            i += 1
        watch.update(now, dt)
        if watch.stepping():
            steps = round(frame / dt)
            for _ in range(steps):
                now += dt
                seen += [(now, ev) for ev in pending.due(now)]
    assert [ev for _, ev in seen] == [ev for _, ev in given]  # every one, in order
    for (t0, _), (t1, _), (w0, _), (w1, _) in zip(seen, seen[1:], given, given[1:], strict=False):
        if w1 < ready_after:  # both held while compiling: released with the spacing they were given with
            assert t1 - t0 >= (w1 - w0) - 2 * dt
        if w1 - w0 > frame + 2 * dt:  # given frames apart: never handed over in one step (a burst)
            assert t1 - t0 >= dt - 1e-9


def test_a_scripted_window_stands_still_until_the_kernels_are_ready():
    from chainsim.game.trainer.compiling import KernelGate

    compiler = _Compiling()
    gate = KernelGate(compiler, ["normals and collision"], scripted=True)
    assert not gate.stepping()
    compiler.done.append("normals and collision")
    assert gate.stepping()


def test_groups_sharing_kernels_compile_one_after_another():
    from chainsim.systems.engine import warmup

    bf64, sc64, bf32 = (warmup.chainmail_group(o, d) for o, d in (("breadth-first", "float64"),
                        ("schill", "float64"), ("breadth-first", "float32")))  # fmt: skip
    assert set(warmup.GROUPS) >= {bf64, sc64, bf32, warmup.GEOMETRY, warmup.MODELS}
    assert warmup.family(bf64) == warmup.family(sc64) != warmup.family(bf32)
    c = warmup.Compiler(groups=[])  # nothing to compile: ready at once, no process started
    assert c.ready() and c.seconds == 0.0
    c.running = {0: bf64}
    assert not c._eligible(sc64) and c._eligible(bf32) and c._eligible(warmup.MODELS)
    c.done.append(bf64)
    assert c._eligible(sc64)


def test_the_scene_needs_its_own_models_kernels():
    from chainsim.game.trainer.compiling import needed_groups
    from chainsim.game.trainer.headless import build_app
    from chainsim.systems.engine import warmup

    app = build_app("loop-demo")  # nothing soft: collision and normals only
    try:
        assert needed_groups(app) == [warmup.GEOMETRY]
    finally:
        app.close()
    app = build_app("prp")  # the needle's soft tissue: the hybrid body (the needle's force is with collision)
    try:
        # no model switch in its layout: the other models compile after, where the scene does not wait
        assert needed_groups(app) == [warmup.GEOMETRY, warmup.HYBRID, warmup.MOVING]
    finally:
        app.close()
    app = build_app("cutting")
    try:
        needed = needed_groups(app)
        assert needed[0] == warmup.GEOMETRY and warmup.chainmail_group("schill", "float64") in needed
        assert {warmup.MOVING, warmup.MODELS, warmup.HYBRID} <= set(needed)  # the m key switches the model
    finally:
        app.close()


def test_first_uploads_take_numpys_normals_equal_to_the_kernels(monkeypatch):
    import numpy as np

    from chainsim.game.render import meshbuf
    from chainsim.systems.engine.meshgen import triangulated_grid

    pos, tris, _links = triangulated_grid(6, 5, spacing=1.0, dim=3)
    pos = pos + np.random.default_rng(1).normal(0.0, 0.3, pos.shape)
    kernel = meshbuf.vertex_normals(pos, tris)
    monkeypatch.setattr(meshbuf, "KERNEL_NORMALS", False)
    np.testing.assert_allclose(meshbuf.vertex_normals(pos, tris), kernel, atol=1e-12)


@pytest.mark.parametrize("threads", [1, 2, 4, 16])
def test_warmup_leaves_out_only_groups_no_body_takes_with_that_many_threads(threads):
    from chainsim.systems.engine import warmup
    from chainsim.systems.engine.kernels import waves

    groups = warmup.reachable(threads)
    assert set(groups) <= set(warmup.GROUPS)
    assert not [g for g in groups if "float32" in g]
    # the level-parallel cascade is compiled exactly where a body would take it on some mesh
    takes = any(waves.parallel_wins(n, threads) for n in (10**4, 10**5, 10**6, 10**7))
    assert (warmup.PARALLEL in groups) == takes
    assert {warmup.GEOMETRY, warmup.MOVING, warmup.HYBRID, warmup.MODELS, warmup.HAPTICS} <= set(groups)


@pytest.mark.parametrize("pack", sorted(p.name for p in (ROOT / "assets").iterdir() if (p / "pack.toml").is_file()))
def test_every_group_a_built_in_pack_needs_is_compiled_by_warmup(pack):
    from chainsim.game.trainer.compiling import needed_groups
    from chainsim.game.trainer.headless import build_app
    from chainsim.systems.engine import warmup

    app = build_app(str(ROOT / "assets" / pack))
    try:
        needed = needed_groups(app)
    finally:
        app.close()
    assert needed and not set(needed) - set(warmup.reachable(1))


def test_a_group_a_pack_asks_for_after_the_rest_are_done_is_compiled():
    from chainsim.systems.engine import warmup

    c = warmup.Compiler(groups=[])
    assert c.ready() and c.ready([warmup.GEOMETRY]) is False
    c.prefer([warmup.GEOMETRY])  # a pack's group the window did not start with (float32 ChainMail)
    assert not c.ready() and c.total == 1
    assert c.wait(300), "the group was not compiled"
    c.close()
    assert c.ready([warmup.GEOMETRY]) and c.done == [warmup.GEOMETRY] and not c.failed


def test_once_the_window_is_up_the_scenes_groups_compile_at_normal_priority_and_the_rest_in_the_background(
    monkeypatch,
):
    import os

    from chainsim.systems.engine import warmup

    # lowering a child already started is refused to an ordinary user: here every renice is taken
    monkeypatch.setattr(os, "setpriority", lambda which, pid, value: None, raising=False)
    c = warmup.Compiler(groups=[warmup.GEOMETRY, warmup.HAPTICS], processes=1)
    c.hurry([warmup.HAPTICS])  # the scene waits on it; the normals group does not
    assert c.wait(300), "the groups were not compiled"
    c.close()
    assert not c.failed
    # whichever child took it: the scene's group at normal priority, the other one at the background's
    assert c.ran_at == {warmup.GEOMETRY: warmup.BACKGROUND_NICE, warmup.HAPTICS: 0}

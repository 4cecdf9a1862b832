"""A browser session on a fresh install: the trainee sees the scene at once while the kernels compile,
their input waits visibly, and it reaches the scene in order once the kernels are there (as at the window)."""

from __future__ import annotations

import io
import time

import chainsim.systems.engine.warmup as warmup
from chainsim.assets import ASSETS_DIR
from chainsim.components.hud import HudState
from chainsim.game.server import train_session
from chainsim.systems.motion.input import InputLog


class _Compiling:
    """The session's kernel compiler on a first start, finishing when the test says."""

    def __init__(self, first=(), processes=None, groups=None):
        self.groups = list(groups or [])
        self.done: list[str] = []
        self.failed: dict[str, str] = {}
        self.seconds = 0.0
        self.started = time.perf_counter()
        self.finished = False
        self.hurried: list[str] | None = None
        self.stopped = False

    def ready(self, names=None) -> bool:
        return self.finished

    def prefer(self, names) -> None:
        pass

    def hurry(self, names) -> None:
        self.hurried = list(names)

    def stop(self) -> None:
        self.stopped = True


def test_the_scene_shows_at_once_and_input_waits_for_the_kernels(monkeypatch):
    made: list[_Compiling] = []
    monkeypatch.setattr(warmup, "Compiler", lambda **kw: made.append(_Compiling(**kw)) or made[-1])
    channel = train_session.Channel(io.BytesIO(), io.BytesIO(b""))
    cfg = {"root": str(ASSETS_DIR / "prp"), "class": "c", "trainee": "t"}
    session = train_session.Session(cfg, channel)
    try:
        compiler, app = made[0], session.app
        assert compiler.groups and "normals and collision" in compiler.groups  # only what the scene needs
        picture = session.frame()  # ready before any kernel is compiled: the page shows the scene
        assert picture is not None and picture.ndim == 3 and picture.std() > 0
        session._first_picture()
        assert compiler.hurried == session.seat.kernels.gate.needed  # the scene's groups at normal priority now
        hud = app.resource(HudState)
        assert hud.doc_open  # prp opens on its reading page, which takes keys while compiling: Esc closes it
        for key in ("escape", "right"):
            for pressed in (True, False):
                session.apply({"t": "in", "ev": {"kind": "key", "key": key, "pressed": pressed}, "seq": 1})
            session.step(1 / 30)
        assert not hud.doc_open
        for _ in range(10):
            session.step(1 / 30)
        keys = [ev for _, ev in app.resource(InputLog).items if getattr(ev, "key", "") == "right"]
        assert not keys  # held ...
        assert any(t.startswith("Your input waits (1 presses") for t, _ in hud.messages)  # ... and said so
        compiler.finished = True
        for _ in range(15):
            session.step(1 / 30)
        keys = [ev.pressed for _, ev in app.resource(InputLog).items if getattr(ev, "key", "") == "right"]
        assert keys == [True, False]  # given in order once ready
        assert any(t.startswith("Ready: the 1 presses and clicks given while preparing") for t, _ in hud.messages)
    finally:
        session.close()
    assert made[0].stopped

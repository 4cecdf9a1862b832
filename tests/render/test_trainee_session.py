"""A trainee's whole session in the real window under Xvfb, driven by xdotool with mouse and keys
only: sign in, read the key page, place the three landmarks, aim with the needle-tip view, insert,
withdraw to the skin and redirect, save two attempts and quit. The window's own screenshots (F12)
are checked: the key table is drawn as a table inside the main view, the tip view has its
crosshair, and `chainsim records list` shows two attempts with their own durations.

Runs where Xvfb and xdotool are installed (CI installs them); skipped elsewhere."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from chainsim.game.trainer.xvfb import start_xvfb

ROOT = Path(__file__).resolve().parents[2]
W, H = 1280, 800
needs_x = pytest.mark.skipif(
    shutil.which("Xvfb") is None or shutil.which("xdotool") is None, reason="Xvfb and xdotool are not installed"
)


def landmark_pixels():
    """Window pixels (top-left origin, as xdotool wants) of the ideal left landmarks."""
    from chainsim.components.loader import PackResource
    from chainsim.game.trainer.headless import build_app
    from chainsim.systems.view.cameras import ViewState, main_view

    app = build_app("prp")
    try:
        vp = main_view(app.resource(ViewState))
        pts = app.resource(PackResource).pack.section("points")
        out = []
        for k in (1, 2, 3):
            x, y, _ = vp.camera.project(np.asarray(pts[f"landmark{k}_ideal_left"]["position"], float)[None], vp.rect)[0]
            out.append((int(x), H - 1 - int(y)))
        return out
    finally:
        app.close()


class Session:
    def __init__(self, tmp: Path):
        self.tmp = tmp
        self.xvfb, self.display = start_xvfb(W, H)
        self.env = {**os.environ, "DISPLAY": self.display, "XDG_CONFIG_HOME": str(tmp / "config")}
        self.env.pop("PYGLET_HEADLESS", None)
        self.db = tmp / "records.sqlite3"
        self.app = subprocess.Popen(
            [sys.executable, "-m", "chainsim.game.cli.main", "play", "prp", "--db", str(self.db)],
            cwd=tmp,
            env=self.env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.wid = self._window()

    def _window(self) -> str:
        for _ in range(240):
            r = subprocess.run(
                ["xdotool", "search", "--name", "chainsim - prp"], env=self.env, capture_output=True, text=True
            )
            if r.stdout.strip():
                time.sleep(3.0)  # first frames drawn
                # on a software renderer the window opens twice (a multisampled try is closed): the
                # one still there is the last found
                r = subprocess.run(
                    ["xdotool", "search", "--name", "chainsim - prp"], env=self.env, capture_output=True, text=True
                )
                return r.stdout.split()[-1]
            if self.app.poll() is not None:
                raise AssertionError(self.app.stdout.read())
            time.sleep(0.5)
        raise AssertionError("the window did not open")

    def xdo(self, *args: str, wait: float = 0.4) -> None:
        subprocess.run(["xdotool", *args], env=self.env, check=True)
        time.sleep(wait)

    def key(self, *keys: str, wait: float = 0.4) -> None:
        for k in keys:
            self.xdo("key", "--window", self.wid, k, wait=wait)

    def type(self, text: str) -> None:
        self.xdo("type", "--window", self.wid, "--delay", "120", text, wait=0.6)

    def click(self, x: int, y: int, wait: float = 0.8) -> None:
        self.xdo("mousemove", "--window", self.wid, str(x), str(y), wait=0.3)
        self.xdo("click", "1", wait=wait)

    def shot(self, name: str) -> np.ndarray:
        before = set(self.tmp.glob("chainsim-shot-*.png"))
        self.key("F12", wait=1.5)
        for _ in range(40):
            new = set(self.tmp.glob("chainsim-shot-*.png")) - before
            if new:
                path = new.pop()
                time.sleep(0.5)
                path.rename(self.tmp / f"{name}.png")
                return np.asarray(Image.open(self.tmp / f"{name}.png").convert("RGB")).astype(int)
            time.sleep(0.25)
        raise AssertionError(f"no screenshot for {name}")

    def close(self) -> str:
        try:
            out, _ = self.app.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            self.app.kill()
            out, _ = self.app.communicate()
        self.xvfb.terminate()
        self.xvfb.wait(timeout=10)
        return out


def widget_centre(name: str) -> tuple[int, int]:
    from chainsim.game.trainer.headless import build_app
    from chainsim.systems.view.cameras import ViewState

    app = build_app("prp")
    try:
        vs = app.resource(ViewState)
        p = next(p for ps in vs.panels.values() for p in ps if p.spec["name"] == name)
        return int(p.rect.x + p.rect.w / 2), H - 1 - int(p.rect.y + p.rect.h / 2)
    finally:
        app.close()


def grid_rows(img: np.ndarray, x0: int, x1: int) -> int:
    """Rows where a long run of table-grid colour crosses the page box."""
    from chainsim.game.render.docview import GRID

    g = np.round(np.array(GRID[:3]) * 255)
    near = np.abs(img[:, x0:x1] - g).max(axis=2) <= 12
    return int((near.mean(axis=1) > 0.5).sum())


@pytest.mark.slow
@needs_x
def test_a_trainee_session_in_the_window(tmp_path):
    lm = landmark_pixels()
    save, reset = widget_centre("save"), widget_centre("reset")
    s = Session(tmp_path)
    try:
        # sign in: class, Tab, name, Enter
        s.type("c1")
        s.key("Tab")
        s.type("alice")
        s.key("Return")
        # the key page: a table with a grid, inside the main view, clear of the controller
        s.key("F1", wait=1.0)
        keys = s.shot("keys")
        assert grid_rows(keys, 40, 700) >= 8
        assert grid_rows(keys, 780, 1270) == 0
        s.key("Escape", wait=1.0)  # closes the page; the face is free to click
        for x, y in lm:
            s.click(x, y, wait=1.2)
        # aim: the correct attempt's dials are about -15.9 and +39.6 degrees
        s.key(*["Left"] * 16, wait=0.15)
        s.key(*["Up"] * 40, wait=0.15)
        aimed = s.shot("aimed")
        cx, cy = 768 + 128, int(800 * 0.19)  # centre of the needle-tip view (beside the C-arm view)
        cross = aimed[cy - 1 : cy + 2, cx + 6 : cx + 14]
        assert (cross.min(axis=2) > 200).any()  # the white crosshair arm right of the centre
        # attempt 1: in a little, back to the skin, redirect, in to the end, save
        s.key("i", "i", "i", wait=0.3)
        s.key("o", "o", "o", wait=0.3)
        time.sleep(1.0)
        s.key("Right", wait=0.3)
        s.key("Left", wait=0.3)
        s.key(*["i"] * 40, wait=0.12)
        time.sleep(1.0)
        s.shot("attempt1")
        s.click(*save, wait=1.5)
        # attempt 2: reset (the landmarks stay), aim a little lower, into bone, save
        time.sleep(2.0)
        s.click(*reset, wait=1.0)
        s.key(*["Up"] * 10, wait=0.15)
        s.key(*["i"] * 20, wait=0.12)
        time.sleep(1.0)
        s.click(*save, wait=1.5)
        s.shot("attempt2")
        # saved: quits without asking. The window may be gone before xdotool sends the key's release
        # (a BadWindow error from xdotool); the app's exit status below is what counts
        subprocess.run(["xdotool", "key", "--window", s.wid, "Escape"], env=s.env, check=False)
        time.sleep(2.0)
    finally:
        out = s.close()
    assert s.app.returncode == 0, out
    r = subprocess.run(
        [sys.executable, "-m", "chainsim.game.cli.main", "records", "list", "--db", str(s.db)],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stderr
    from chainsim.game.records.store import RecordStore

    with RecordStore(s.db) as store:
        rows = store.list_attempts("c1", "alice")
    assert len(rows) == 2, r.stdout
    a1, a2 = rows
    assert a1["duration_s"] != a2["duration_s"]
    assert sum(a2["step_times"].values()) == pytest.approx(a2["duration_s"], abs=1e-6)
    assert a1["redirections"] >= 1

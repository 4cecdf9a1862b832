"""What users get on disk: snapshots, frame series from headless runs, and a clear exit without EGL."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]


def _cli(*args, env=None):
    return subprocess.run(
        [sys.executable, "-m", "game", *args], cwd=ROOT, capture_output=True, text=True, env=env, timeout=300
    )


def test_snapshot_writes_the_whole_layout(tmp_path):
    out = tmp_path / "shot.png"
    r = _cli("snapshot", "loop-demo", "--out", str(out), "--size", "400x250")
    assert r.returncode == 0, r.stderr
    img = np.asarray(Image.open(out).convert("RGB")).astype(int)
    assert img.shape == (250, 400, 3)
    # loop-demo: scene on the left 75 %, control panel on the right 25 % (split at x = 300)
    panel = img[120:, 305:]
    from chainsim.game.render.renderer import PANEL_BG

    want = [round(c * 255) for c in PANEL_BG[:3]]
    assert np.median(panel.reshape(-1, 3), axis=0).tolist() == want
    scene = img[:, :295]
    assert (np.abs(scene - scene[2, 150]).sum(axis=2) > 60).mean() > 0.2  # objects drawn over the background


def test_snapshot_without_egl_exits_2_with_one_line(tmp_path):
    env = dict(os.environ, __EGL_VENDOR_LIBRARY_FILENAMES="/nonexistent.json", __EGL_VENDOR_LIBRARY_DIRS="/nonexistent")
    r = _cli("snapshot", "loop-demo", "--out", str(tmp_path / "x.png"), env=env)
    assert r.returncode == 2
    assert "EGL" in r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "x.png").exists()


def test_headless_run_writes_every_kth_frame(tmp_path):
    from chainsim.game.trainer.headless import run_pack

    run_pack("loop-demo", 5, out=str(tmp_path), screenshot_every=2, size=(160, 100))
    frames = sorted(p.name for p in tmp_path.glob("frame_*.png"))
    assert frames == ["frame_000000.png", "frame_000002.png", "frame_000004.png"]
    a = np.asarray(Image.open(tmp_path / "frame_000000.png"))
    b = np.asarray(Image.open(tmp_path / "frame_000004.png"))
    assert a.shape == (100, 160, 3)
    assert not np.array_equal(a, b)  # the ball moved

"""The real pyglet window under Xvfb: opens, obeys scripted clicks and keys, saves a screenshot and a
recording that replays headless to the same digest. Skipped where Xvfb is not installed."""

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

ROOT = Path(__file__).resolve().parents[2]

SCRIPT = """
format = 1
[[event]]
t = 0.2
kind = "mouse_button"
x = 1000.0
y = 752.0
pressed = true
[[event]]
t = 0.25
kind = "mouse_button"
x = 1000.0
y = 752.0
pressed = false
[[event]]
t = 0.4
kind = "key"
key = "f1"
"""


@pytest.mark.skipif(shutil.which("xvfb-run") is None, reason="xvfb-run is not installed")
def test_window_plays_a_script_and_saves_what_it_shows(tmp_path):
    from chainsim.game.render.renderer import ACCENT, PANEL_BG

    script = tmp_path / "s.toml"
    script.write_text(SCRIPT, encoding="utf-8")
    shot, rec, times = tmp_path / "w.png", tmp_path / "rec.json", tmp_path / "frames.csv"
    r = subprocess.run(
        [
            "xvfb-run",
            "-a",
            "-s",
            "-screen 0 1400x900x24",
            sys.executable,
            "-m",
            "game",
            "play",
            "loop-demo",
            "--input",
            str(script),
            "--exit-after",
            "0.8",
            "--screenshot",
            str(shot),
            "--record",
            str(rec),
            "--frame-times",
            str(times),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    img = np.asarray(Image.open(shot).convert("RGB")).astype(int)
    assert img.shape == (800, 1280, 3)
    # the click at (1000, 752) hit the "Show rod" toggle: its box (window x 970..986) is now empty
    box = img[800 - 752, 978]
    assert np.abs(box - np.round(np.array(PANEL_BG[:3]) * 255)).max() <= 3
    assert np.abs(box - np.round(np.array(ACCENT[:3]) * 255)).max() > 40
    # F1 opened the help box in the middle of the window (dark fill over the scene)
    assert np.median(img[390:410, 600:680].max(axis=2)) < 40
    r2 = subprocess.run(
        [sys.executable, "-m", "game", "replay", str(rec)], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert r2.returncode == 0, r2.stdout + r2.stderr
    assert "matches" in r2.stdout
    # the frame log: one row per frame, times that add up to the session
    rows = [line.split(",") for line in times.read_text(encoding="utf-8").splitlines()]
    assert rows[0] == ["t_s", "interval_ms", "work_ms"]
    t, interval, work = (np.array([float(r[k]) for r in rows[1:]]) for k in range(3))
    assert len(t) >= 10 and np.all(np.diff(t) >= 0) and np.all(work > 0)
    assert abs(interval[1:].sum() / 1e3 - (t[-1] - t[0])) < 0.05


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("Xvfb") is None or shutil.which("xdotool") is None, reason="needs Xvfb and xdotool")
def test_bench_window_drives_the_real_window_and_reports_each_phase(tmp_path):
    """`chainsim bench window` opens the prp window under Xvfb, turns a dial and orbits by dragging,
    with the skin opaque and see-through, runs live fluoroscopy, and reports the frame rate of each
    phase from the window's own frame log."""
    out = tmp_path / "bw"
    r = subprocess.run(
        [sys.executable, "-m", "game", "bench", "window", "--seconds", "1.5", "--out", str(out)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    rows = [line.split("|")[1:-1] for line in (out / "results.md").read_text().splitlines() if line.startswith("| ")]
    phases = {c[0].strip(): c for c in rows[1:]}
    assert set(phases) == {
        "still",
        "turning a dial",
        "orbiting",
        "see-through still",
        "see-through orbiting",
        "see-through turning a dial",
        "live fluoroscopy",
        "live fluoroscopy turning a dial",
    }
    for name, cells in phases.items():
        frames, fps = int(cells[1]), float(cells[3])
        assert frames >= 5 and 0 < fps <= 70, name  # the window paces itself at 60 fps at most
    # the drags and the click reached the window: replayed, the recording written on quitting ends
    # with the dial turned and the skin see-through, and replays to the window's digest
    import json

    from chainsim.components.resources import PendingInput
    from chainsim.game.trainer.headless import build_app
    from chainsim.game.trainer.inputscript import load_script
    from chainsim.systems.view.ui.widgets import WidgetState

    rec = out / "session.json"
    app = build_app("prp")
    try:
        app.resource(PendingInput).extend(load_script(rec))
        app.run_steps(json.loads(rec.read_text())["steps"])
        values = app.resource(WidgetState).values
        assert values["skin_transparent"] is True
        assert abs(float(values["rotate_horizontal"])) > 1.0
        # the Live switch was clicked on and off again: live seconds were counted, none run now
        import esper

        from chainsim.components.resources import EntityIndex
        from chainsim.systems.procedures.needle.carm import CArm

        with app.active():
            carm = esper.component_for_entity(app.resource(EntityIndex).get("carm"), CArm)
        assert carm.live_s > 1.0 and not carm.live
    finally:
        app.close()
    r2 = subprocess.run(
        [sys.executable, "-m", "game", "replay", str(rec)], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert r2.returncode == 0 and "matches" in r2.stdout, r2.stdout + r2.stderr

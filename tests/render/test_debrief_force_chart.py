"""With a force-feedback device, the window's debrief draws the force the hand felt against the needle's depth in a
chart above it, each layer's give marked; without a device there is no chart."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import tomli_w
from conftest import open_app

from chainsim.components.hud import HudState
from chainsim.components.input_events import Key
from chainsim.components.resources import PendingInput
from chainsim.game.render import panelview
from chainsim.game.render.render_system import draw, read_pixels
from chainsim.game.trainer.inputscript import load_script
from chainsim.systems.engine.haptics import simdevice as D
from chainsim.systems.procedures.needle import haptics as H
from chainsim.systems.view.cameras import ViewState, main_view

ROOT = Path(__file__).resolve().parents[2]
BLUE = np.array([0.45, 0.7, 1.0]) * 255  # the chart's line (panelview.force_chart)


def _aim(tmp_path: Path) -> Path:
    script = tomllib.loads((ROOT / "assets/prp/scripts/correct.toml").read_text())
    script["event"] = [e for e in script["event"] if e["t"] < 4.0 and e.get("name") != "insert"]
    path = tmp_path / "aim.toml"
    path.write_text(tomli_w.dumps(script))
    return path


def _debrief(app) -> None:
    t = app.time.sim_time
    app.resource(PendingInput).extend([(t, Key("a", True)), (t + 0.05, Key("a", False))])
    app.run_steps(20)


def _chart_pixels(app) -> int:
    """Pixels of the chart's line colour in the box the chart takes at the main view's right end."""
    vs = app.resource(ViewState)
    r = main_view(vs).rect
    rgba = read_pixels(app)[::-1]  # bottom row first, as the overlay counts
    w, h = panelview.FORCE_CHART
    box = rgba[int(r.y) : int(r.y + r.h), int(r.x + r.w - w - 8) : int(r.x + r.w - 8), :3].astype(float)
    return int((np.abs(box - BLUE).max(axis=2) < 40).sum())


def test_a_device_attempts_debrief_draws_its_force_chart(gl_ctx, tmp_path):
    app = open_app("prp", size=(1280, 800))
    try:
        app.resource(PendingInput).extend(load_script(_aim(tmp_path)))
        H.attach(app, "sim", traj=D.scripted([(0.0, -2.0), (2.0, -2.0), (6.0, 40.0), (7.0, 40.0)]))
        app.run_steps(9 * 120)
        _debrief(app)
        hud = app.resource(HudState)
        assert hud.debrief and hud.debrief_force
        assert any(int(e) & 1 for _d, _f, e in hud.debrief_force)  # the skin's give is among the points
        draw(app)
        assert _chart_pixels(app) > 150  # the force line is drawn
    finally:
        app.close()


def test_without_a_device_the_debrief_has_no_chart(gl_ctx, tmp_path):
    app = open_app("prp", size=(1280, 800))
    try:
        app.resource(PendingInput).extend(load_script(ROOT / "assets/prp/scripts/correct.toml"))
        app.run_steps(7 * 120)
        _debrief(app)
        hud = app.resource(HudState)
        assert hud.debrief and not hud.debrief_force
        draw(app)
        assert _chart_pixels(app) < 20
    finally:
        app.close()

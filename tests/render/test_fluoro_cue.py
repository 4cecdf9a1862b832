"""The window's X-ray cue: between the shot and its image the C-arm view says an image is being made,
drawn at once, and the image follows on the next frame (chainsim.game.render.radiograph, FluoroRenderer)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from conftest import open_app

from chainsim.components.input_events import Widget
from chainsim.components.resources import PendingInput
from chainsim.game.render.panelview import MESSAGE
from chainsim.game.render.render_system import RenderTarget, draw, read_pixels
from chainsim.game.render.renderer import Renderer
from chainsim.game.trainer.inputscript import load_script

PACK = Path(__file__).resolve().parents[2] / "assets" / "prp"


def _cue_pixels(app, frame) -> int:
    """Pixels of the cue's colour in the middle third of the C-arm view."""
    view = next(v for v in frame.views if v.kind == "fluoro")
    img = read_pixels(app)[:, :, :3].astype(int)
    r, s, h = view.rect, app.resource(RenderTarget).scale, img.shape[0]
    x0, x1 = int((r.x + r.w / 3) * s), int((r.x + 2 * r.w / 3) * s)
    y0, y1 = int(h - (r.y + 2 * r.h / 3) * s), int(h - (r.y + r.h / 3) * s)
    mid = img[y0:y1, x0:x1].reshape(-1, 3)
    colour = np.array([round(c * 255) for c in MESSAGE[:3]])
    return int((np.abs(mid - colour).max(axis=1) <= 30).sum())


def _step(app, events=()):
    app.resource(PendingInput).extend(list(events))
    app.update(app.time.dt)


def test_a_shot_in_the_window_shows_its_cue_at_once_then_its_image(gl_ctx):
    app = open_app(str(PACK))
    try:
        renderer = app.resource(Renderer)
        renderer.defer_shots = True  # as the window sets it
        events = load_script(PACK / "scripts" / "correct.toml")
        first = min(t for t, e in events if isinstance(e, Widget) and e.name == "xray_take")
        app.resource(PendingInput).extend([e for e in events if e[0] < first])
        for _ in range(int(first / app.time.dt) + 1):
            app.update(app.time.dt)
        fr = renderer.fluoro
        assert fr.defer_shots and fr.image_id <= 0 and not fr.shown
        assert _cue_pixels(app, draw(app)) == 0  # no cue before the shot

        _step(app, [(app.time.sim_time + 1e-6, Widget("xray_take", None))])
        _step(app)  # more steps before a frame is drawn: still no image made unseen
        assert fr.waiting > 0 and not fr.shown
        assert _cue_pixels(app, draw(app)) > 20  # the frame drawn after the press says so

        _step(app)  # the next frame makes the image
        frame = draw(app)
        assert fr.shown and fr.waiting == 0 and fr.image_id > 0
        assert _cue_pixels(app, frame) == 0
    finally:
        app.close()


def test_off_screen_the_image_is_made_at_the_shot(gl_ctx):
    app = open_app(str(PACK))
    try:
        fr = app.resource(Renderer).fluoro
        events = load_script(PACK / "scripts" / "correct.toml")
        first = min(t for t, e in events if isinstance(e, Widget) and e.name == "xray_take")
        app.resource(PendingInput).extend([e for e in events if e[0] <= first])
        for _ in range(int(first / app.time.dt) + 2):
            app.update(app.time.dt)
        assert fr.shown and fr.waiting == 0 and not fr.defer_shots
    finally:
        app.close()

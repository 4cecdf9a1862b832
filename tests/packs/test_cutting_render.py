"""The cutting pack drawn off screen (EGL): a cut in the top layer opens a gap through which the layer
beneath shows, and the uncut tissue either side still covers it (thesis 4.5.2, Fig. 4.8)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from chainsim.components.input_events import Widget
from chainsim.components.resources import PendingInput
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script

SCRIPT = Path(__file__).resolve().parents[2] / "assets" / "cutting" / "scripts" / "cut-and-open.toml"


@pytest.fixture(scope="module")
def cut_frame():
    from chainsim.game.render.context import GLUnavailable, egl_context

    try:
        egl_context()
    except GLUnavailable as e:
        pytest.skip(f"no EGL OpenGL 3.3 context: {e}")
    from chainsim.game.render.render_system import draw, read_pixels
    from chainsim.systems.view.cameras import ViewState

    app = build_app("cutting", render=True)
    try:
        # the cut only (the script takes up the forceps at 1.0 s), blade lifted so the red path is hidden
        app.resource(PendingInput).extend(
            [te for te in load_script(SCRIPT) if te[0] < 0.95] + [(0.9, Widget("release"))]
        )
        for _ in range(114):
            app.update(app.time.dt)
        draw(app)
        rgba = read_pixels(app)
        vp = app.resource(ViewState).get("controller")
        yield rgba, vp.camera, vp.rect
    finally:
        app.close()


def colour_at(rgba, camera, rect, point) -> np.ndarray:
    x, y, _ = camera.project(np.asarray([point], float), rect)[0]
    row = rgba.shape[0] - 1 - int(y)  # read_pixels gives the top row first
    return rgba[row, int(x), :3].astype(float)


def test_the_cut_shows_the_layer_beneath(cut_frame):
    rgba, cam, rect = cut_frame
    assert cam.pitch == 75.0  # the scissors' view

    # the top layer is tan (more red than blue), the layer beneath pale lilac (more blue than red); under
    # the same light a few millimetres either side, the gap is markedly bluer than the tissue around it
    def blueness(c):
        return c[2] - c[0]

    for y in (-20.0, -10.0, 0.0, 10.0, 20.0):
        gap = colour_at(rgba, cam, rect, (0.6, y, 0.0))
        for x in (-4.0, 5.0):
            top = colour_at(rgba, cam, rect, (x, y, 0.0))
            assert top[0] > top[2], f"top layer missing at ({x}, {y}): {top}"
            assert blueness(gap) > blueness(top) + 30, f"no gap at y = {y}: {gap} vs {top}"

"""The needle-tip view shows what lies ahead of the tip from the first landmark on: at depth 0 its
camera sits on the entry mark, which must not fill the view (the mental-block trainer's tip view was
one flat yellow before the needle went in)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import open_app

from chainsim.components.input_events import PickPoint
from chainsim.components.resources import PendingInput
from chainsim.game.render.render_system import RenderTarget, draw, read_pixels
from chainsim.game.trainer.inputscript import load_script

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("pack", ["mental-block", "prp"])
def test_tip_view_at_depth_zero_shows_the_scene_not_the_entry_mark(gl_ctx, pack):
    app = open_app(str(ROOT / "assets" / pack), size=(1280, 800))
    try:
        events = load_script(ROOT / "assets" / pack / "scripts" / "correct.toml")
        picks = [(t, e) for t, e in events if isinstance(e, PickPoint)]
        app.resource(PendingInput).extend(picks)
        for _ in range(int((max(t for t, _ in picks) + 0.2) / app.time.dt)):
            app.update(app.time.dt)
        frame = draw(app)
        view = next(v for v in frame.views if v.name == "tip")
        img = read_pixels(app)[:, :, :3]
        h = img.shape[0]
        r = view.rect
        s = app.resource(RenderTarget).scale
        x0, y0, x1, y1 = int(r.x * s), int(h - (r.y + r.h) * s), int((r.x + r.w) * s), int(h - r.y * s)
        tip = img[y0 + 30 : y1 - 10, x0 + 10 : x1 - 10].astype(int)
        # a flat fill is one colour over nearly all the view; the scene ahead has shading and edges
        px = tip.reshape(-1, 3)
        values, counts = np.unique(px // 8, axis=0, return_counts=True)
        assert counts.max() / len(px) < 0.5, f"the tip view is one colour {values[counts.argmax()] * 8}"
    finally:
        app.close()

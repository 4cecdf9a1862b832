"""Fluoroscopy first, as drawn: the needle-tip view keeps its crosshair but shows no target ring and no
distance, only a note to guide by the X-ray; without the mode the ring and its distance are there."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from chainsim.components.input_events import PickPoint
from chainsim.components.resources import PendingInput
from chainsim.game.render.panelview import AIM
from chainsim.game.render.render_system import RenderTarget, draw, read_pixels
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script

ROOT = Path(__file__).resolve().parents[2]


def tip_view_aim_pixels(pack: str, settings) -> int:
    """Pixels of the aiming aid's green in the tip view once the landmarks are placed (the target's own
    green surface, where the view sees it, counts in both modes)."""
    app = build_app(str(ROOT / "assets" / pack), render=True, headless=True, size=(1280, 800), settings=settings)
    try:
        events = load_script(ROOT / "assets" / pack / "scripts" / "correct.toml")
        picks = [(t, e) for t, e in events if isinstance(e, PickPoint)]
        app.resource(PendingInput).extend(picks)
        for _ in range(int((max(t for t, _ in picks) + 0.2) / app.time.dt)):
            app.update(app.time.dt)
        frame = draw(app)
        view = next(v for v in frame.views if v.name == "tip")
        img = read_pixels(app)[:, :, :3].astype(int)
        h = img.shape[0]
        r, s = view.rect, app.resource(RenderTarget).scale
        x0, y0, x1, y1 = int(r.x * s), int(h - (r.y + r.h) * s), int((r.x + r.w) * s), int(h - r.y * s)
        tip = img[y0:y1, x0:x1].reshape(-1, 3)
        green = np.array([round(c * 255) for c in AIM[:3]])
        return int((np.abs(tip - green).max(axis=1) <= 24).sum())
    finally:
        app.close()


@pytest.mark.parametrize("pack", ["prp", "mental-block"])
def test_fluoro_first_draws_no_target_ring_in_the_tip_view(gl_ctx, pack):
    shown = tip_view_aim_pixels(pack, None)
    hidden = tip_view_aim_pixels(pack, {"fluoro_first": True})
    # the ring and the distance's text are a few hundred pixels of their own
    assert shown - hidden > 100, f"{shown} green pixels with the aid, {hidden} with fluoroscopy first"

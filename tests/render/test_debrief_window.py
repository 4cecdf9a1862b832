"""The debrief fits the window a trainee has: after a failed attempt in prp and in mental-block, drawn
off screen (EGL) as the window draws it at 1280x800 and at 1024x768, every line of the debrief lies
inside the surgeon's view, none is cut short, every word of every row is shown, and the box is there
in the picture (dark behind the text)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from chainsim.components.hud import HudState
from chainsim.components.resources import PendingInput
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script

REPO = Path(__file__).resolve().parents[2]
SCRIPTS = {
    "prp": REPO / "docs" / "images" / "prp-debrief.toml",
    "mental-block": REPO / "assets" / "mental-block" / "scripts" / "bone.toml",
}


@pytest.mark.parametrize("size", [(1280, 800), (1024, 768)], ids=["1280x800", "1024x768"])
@pytest.mark.parametrize("pack", ["prp", "mental-block"])
def test_every_line_of_the_debrief_is_inside_the_window(pack, size):
    from chainsim.game.render import panelview
    from chainsim.game.render.render_system import draw, read_pixels
    from chainsim.game.render.renderer import Renderer
    from chainsim.systems.view.cameras import ViewState

    app = build_app(pack, render=True, size=size)
    try:
        events = load_script(SCRIPTS[pack])
        app.resource(PendingInput).extend(events)
        app.run_steps(int((events[-1][0] + 0.5) * 120))
        h = app.resource(HudState)
        assert h.debrief and "FAILED" in h.debrief[0][0], h.debrief[:1]
        draw(app)
        rgba = read_pixels(app)[:, :, :3].astype(int)
        assert rgba.shape[:2] == (size[1], size[0])
        ov = app.resource(Renderer).overlay
        vs = app.resource(ViewState)
        orbit = [v for v in vs.viewports if v.kind == "orbit"]
        assert orbit, [v.name for v in vs.viewports]
        r = orbit[0].rect  # the surgeon's view, where the window puts the HUD and the debrief
        fit = panelview.debrief_fit(ov, h.debrief, r, 1.0)
        f = fit.font
        # the box, and every line in it, inside the surgeon's view
        assert r.x <= fit.x and fit.x + fit.w <= r.x + r.w and r.y <= fit.y
        top = fit.y + fit.h - fit.pad / 2
        assert top - len(fit.lines) * f.line_h >= r.y, "lines below the view's bottom edge"
        assert fit.y + fit.h <= r.y + r.h - 2 * f.line_h, "the box reaches the top band"
        # nothing cut short (the overlay cuts text wider than its room with '...')
        for line in fit.lines:
            for text, _tone, dx in line:
                assert f.width(text) <= fit.max_w(dx) + 0.5, text
        # every word of every row is on some line
        shown = " ".join(t for line in fit.lines for t, _tone, _dx in line).split()
        for text, _tone in h.debrief:
            for word in text.split():
                assert word in shown, (word, text)
        # the dark box is drawn where the layout says (window rows run bottom-up)
        H = rgba.shape[0]
        y0, y1 = int(fit.y + 2), int(fit.y + fit.h - 2)
        box = rgba[H - y1 : H - y0, int(fit.x + 2) : int(fit.x + fit.w - 2)]
        assert np.median(box) < 60, "no dark debrief box where the layout puts it"
    finally:
        app.close()

"""The trainer panel's buttons at the window sizes trainees use: every label whole, a narrow button's in a
smaller font rather than cut short."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import open_app

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("pack", ["prp", "mental-block"])
@pytest.mark.parametrize("size", [(1024, 768), (1280, 800)])
def test_every_button_label_is_whole_at_the_window_sizes_trainees_use(gl_ctx, pack, size):
    """No button's label is cut short ("My attem...") at 1024x768 or 1280x800: a narrow button draws its
    label in a smaller font, down to BUTTON_FONT_MIN of the panel's."""
    from chainsim.game.render import panelview
    from chainsim.game.render.renderer import Renderer
    from chainsim.systems.view.cameras import ViewState

    app = open_app(str(ROOT / "assets" / pack), size=size)
    ov = app.resource(Renderer).overlay  # the window's own fonts
    try:
        vs = app.resource(ViewState)
        buttons = [p for ps in vs.panels.values() for p in ps if p.spec["kind"] == "button"]
        assert len(buttons) >= 8
        for p in buttons:
            f = ov.font_for(p.rect.h)
            label, key = p.spec.get("label") or p.spec["name"], f" [{p.spec['key']}]" if p.spec.get("key") else ""
            text, font = panelview.button_label(ov, f, label, key, p.rect.w - 8)
            assert text.startswith(label) and font.width(text) <= p.rect.w - 8, (p.spec["name"], text)
            assert font.font.size >= panelview.BUTTON_FONT_MIN * f.font.size
    finally:
        app.close()

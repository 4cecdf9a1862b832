"""The layout in every X-ray mode at the window sizes trainees use (1024x768, 1280x800, full HD): the step
text and F1's pages go to the biggest view, the C-arm view's status line fits once the view is large,
and the controller's buttons keep their labels whole."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import open_app

from chainsim.components.input_events import Widget
from chainsim.components.resources import PendingInput

PACK = Path(__file__).resolve().parents[2] / "assets" / "prp"
SIZES = [(1024, 768), (1280, 800), (1920, 1080)]
#: presses of Big X-ray (v): the small monitor, the monitor in the surgeon's view's place, the whole window
MODES = [0, 1, 2]
#: the longest status line a shot can have (the preset's name, the arm's angles, counts, dose)
STATUS = "Submental-oblique (az -180, el -90) - 99 images, 99.9 s, 99.99 mGy"


@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("mode", MODES)
def test_every_x_ray_mode_keeps_text_pages_and_labels_whole(gl_ctx, size, mode):
    from chainsim.game.render import panelview
    from chainsim.game.render.renderer import Renderer
    from chainsim.systems.view.cameras import ViewState, main_view
    from chainsim.systems.view.ui import docbox

    app = open_app(str(PACK), size=size)
    try:
        vs = app.resource(ViewState)
        for _ in range(mode):
            app.resource(PendingInput).push(app.time.sim_time, Widget("enlarge:carm", None))
            app.update(app.time.dt)
        views = [v for v in vs.viewports if v.visible and v.kind != "panel" and v.rect.w > 0 and v.rect.h > 0]
        biggest = max(views, key=lambda v: v.rect.w * v.rect.h)
        main = main_view(vs)
        # F1's pages and the step text are drawn in the main view: never a small inset beside a big view
        assert main.rect.w * main.rect.h >= 0.9 * biggest.rect.w * biggest.rect.h, (main.name, biggest.name)
        page = docbox.box(main.rect)
        assert page.w >= min(0.6 * main.rect.w, docbox.MAX_W) and page.h >= 0.6 * main.rect.h
        ov = app.resource(Renderer).overlay
        carm = vs.get("carm").rect
        if mode:  # a large monitor: the whole status line is read, not cut short
            assert ov.font.width(STATUS) <= carm.w - 12, (carm.w, ov.font.width(STATUS))
        for p in [p for ps in vs.panels.values() for p in ps if p.spec["kind"] == "button"]:
            if p.rect.w <= 0:
                continue
            f = ov.font_for(p.rect.h)
            label, key = p.spec.get("label") or p.spec["name"], f" [{p.spec['key']}]" if p.spec.get("key") else ""
            text, font = panelview.button_label(ov, f, label, key, p.rect.w - 8)
            assert text.startswith(label) and font.width(text) <= p.rect.w - 8, (p.spec["name"], text)
    finally:
        app.close()

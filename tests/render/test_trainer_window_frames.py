"""The cutting trainer's and the ChainMail demos' first frames, drawn off screen (EGL) as the window
draws them: the tissue stands clear of every edge of both views (nothing cut off), the demo's marked
element is drawn where it is, and the cutting Help button puts its page over the Viewer."""

from __future__ import annotations

import esper
import numpy as np
import pytest

from chainsim.components.core import Transform
from chainsim.components.input_events import Widget
from chainsim.components.resources import EntityIndex, PendingInput
from chainsim.game.trainer.headless import build_app
from chainsim.systems.procedures.demo.procedure import MARK_COLOR
from chainsim.systems.view.cameras import ViewState


@pytest.fixture(scope="module", autouse=True)
def egl():
    from chainsim.game.render.context import GLUnavailable, egl_context

    try:
        egl_context()
    except GLUnavailable as e:
        pytest.skip(f"no EGL OpenGL 3.3 context: {e}")


def frame(pack: str, events=(), steps: int = 2):
    from chainsim.game.render.render_system import draw, read_pixels

    app = build_app(pack, render=True)
    app.resource(PendingInput).extend([(0.001, ev) for ev in events])
    app.run_steps(steps)
    draw(app)
    return app, read_pixels(app)[:, :, :3].astype(int)


def view_pixels(rgba, r):
    """The view's pixels, bottom row first (window coordinates)."""
    h = rgba.shape[0]
    return rgba[h - r.y - r.h : h - r.y, r.x : r.x + r.w][::-1]


@pytest.mark.parametrize("pack", ["cutting", "chainmail-demo"])
def test_the_tissue_stands_clear_of_every_edge_of_both_views(pack):
    app, rgba = frame(pack)
    try:
        vs = app.resource(ViewState)
        for vp in (v for v in vs.viewports if v.kind in ("orbit", "fixed")):
            px = view_pixels(rgba, vp.rect)
            background = px[2, vp.rect.w // 2]
            differs = np.abs(px - background).max(axis=2) > 12
            assert differs.mean() > 0.01, vp.name  # the tissue is there (a wireframe covers little)
            sides = differs[: vp.rect.h - 40]  # the caption and the step text sit along the top
            border = np.concatenate([differs[:4].ravel(), sides[:, :4].ravel(), sides[:, -4:].ravel()])
            assert not border.any(), f"{pack}: the tissue touches an edge of the {vp.name} view"
    finally:
        app.close()


def test_the_demo_draws_its_marked_element():
    app, rgba = frame("chainmail-demo")
    try:
        with app.active():
            mark = app.resource(EntityIndex).get("patch.marked")
            where = np.asarray(esper.component_for_entity(mark, Transform).position, float)
        green = np.round(np.array(MARK_COLOR[:3]) * 255)
        vs = app.resource(ViewState)
        for name in ("main", "grab"):
            vp = vs.get(name)
            x, y, _ = vp.camera.project(where[None], vp.rect)[0]
            h = rgba.shape[0]
            patch = rgba[h - 1 - int(y) - 4 : h - int(y) + 4, int(x) - 4 : int(x) + 5]
            # lit, so not the exact colour: green well above red and blue somewhere around the element
            assert ((patch[..., 1] > 150) & (patch[..., 1] - patch[..., 0] > 80)).any(), (name, green)
    finally:
        app.close()


def test_the_cutting_help_button_shows_its_page_over_the_viewer():
    from chainsim.game.render.docview import BOX_BG
    from chainsim.systems.view.ui import docbox

    app, rgba = frame("cutting", [Widget("help")])
    try:
        vs = app.resource(ViewState)
        b = docbox.box(vs.get("viewer").rect)
        px = view_pixels(rgba, b)
        dark = np.abs(px - np.round(np.array(BOX_BG[:3]) * 255)).max(axis=2) <= 40
        assert dark.mean() > 0.4  # the page's dark background (with its text on it) covers the box
        assert not (view_pixels(rgba, vs.get("controller").rect) == px[5, 5]).all()  # the Controller is not covered
    finally:
        app.close()

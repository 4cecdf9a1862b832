"""Every scene of every built-in pack renders a frame: each visible 3-D viewport shows something
besides its background, and GL reports no error."""

import numpy as np
import pytest
from conftest import frame_pixels, open_app

from chainsim.game.packs import pack as packs


def _scenes():
    out = []
    for found in packs.discover():
        if found.source != "builtin":
            continue
        pack, problems = packs.validate(found.path, load_meshes=False)
        names = pack.scene_names() if pack is not None and not problems else [None]
        out += [f"{found.name}/{s}" if s else found.name for s in names]
    return out


@pytest.mark.parametrize("ref", _scenes())
def test_scene_renders_a_frame(ref):
    from chainsim.systems.view.cameras import ViewState

    app = open_app(ref, size=(320, 200))
    try:
        app.update(app.time.dt)
        frame, rgba = frame_pixels(app)  # scene only: no titles, HUD or panels to count as drawn
        background = tuple(round(c * 255) for c in frame.background[:3])
        img = rgba[:, :, :3]
        views = [v for v in app.resource(ViewState).viewports if v.visible and v.is_3d]
        assert views
        for v in views:
            r = v.rect
            region = img[r.y : r.y + r.h, r.x : r.x + r.w].reshape(-1, 3)
            drawn = np.any(region != background, axis=1).mean()
            assert drawn > 0.01, f"viewport {v.name} shows only its background"
    finally:
        app.close()


SCRIPTS = [
    ("prp", "scripts/correct.toml", 900),
    ("mental-block", "scripts/correct.toml", 600),
    ("cutting", "scripts/cut-and-open.toml", 600),
    ("chainmail-demo", "scripts/pull.toml", 300),
]


@pytest.mark.slow
@pytest.mark.parametrize("ref,script,steps", SCRIPTS)
def test_window_view_images_and_layers_draw_what_a_fresh_frame_draws(ref, script, steps):
    """The window keeps view images and layers (a still view copied; a moving needle, tissue or
    instrument drawn over the image of the rest). Through a whole scripted attempt - landmarks,
    aiming, insertion, X-rays; cuts, pulls, a flap opened - every sampled frame equals the same frame
    drawn afresh, but for a pixel or two where a moving item meets another surface at equal depth."""
    from chainsim.components.loader import PackResource
    from chainsim.components.resources import PendingInput
    from chainsim.game.render import render_system as render
    from chainsim.game.render.renderer import Renderer
    from chainsim.game.trainer.inputscript import load_script

    app = open_app(ref, size=(640, 400))
    try:
        app.resource(PendingInput).extend(load_script(app.resource(PackResource).pack.file(script)))
        app.resource(render.RenderTarget).samples = 1
        r = app.resource(Renderer)
        r.cache_views(True)
        vc = r.view_cache
        for k in range(steps):
            app.update(app.time.dt)
            if k % 3:
                continue
            r.view_cache = None
            render.draw(app)
            fresh = render.read_pixels(app).astype(np.int16)
            r.view_cache = vc
            render.draw(app)
            kept = render.read_pixels(app).astype(np.int16)
            assert np.count_nonzero(np.abs(kept - fresh).max(axis=-1) > 2) <= 3, f"step {k}"
        assert vc.reused > 0
    finally:
        app.close()

"""The window's frames while a dial turns are the same with the triangle culling of big meshes and the
labels laid out after the rest of the overlay as without them (chainsim.game.render.culling; the
needle-tip view redrawn each frame and the see-through skin blended again around the needle)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.render.conftest import open_app


@pytest.mark.parametrize("see_through", [False, True])
def test_turning_a_dial_draws_the_same_frames_with_and_without_the_shortcuts(see_through):
    from chainsim.components.input_events import Widget
    from chainsim.components.loader import PackResource
    from chainsim.components.resources import PendingInput
    from chainsim.game.render import render_system as render
    from chainsim.game.render.renderer import Renderer
    from chainsim.game.trainer.inputscript import load_script

    app = open_app("prp", size=(960, 600))
    try:
        pres = app.resource(PackResource)
        pending = app.resource(PendingInput)
        pending.extend(load_script(pres.pack.file("scripts/correct.toml")))
        app.run_steps(int(1.9 / app.time.dt))  # landmarks placed and labelled, needle at the skin
        del pending.items[pending.cursor :]
        app.resource(render.RenderTarget).samples = 1
        r = app.resource(Renderer)
        pending.push(app.time.sim_time, Widget("skin_transparent", see_through))
        app.update(app.time.dt)
        culled_draws = 0
        for k in range(6):
            pending.push(app.time.sim_time, Widget("rotate_horizontal", 2.0 * k))
            app.update(app.time.dt)
            # every view drawn straight, and as in the window: views kept as images, the needle drawn
            # over the surgeon's view with the see-through skin blended again around it
            for cached in (False, True):
                r.cache_views(cached)
                render.draw(app)  # the view images and layers this frame draws from, made once
                frames = {}
                for on in (True, False):
                    r.cull_outside = r.defer_labels = on
                    render.draw(app)
                    frames[on] = render.read_pixels(app).copy()
                r.cull_outside = r.defer_labels = True
                assert np.array_equal(frames[True], frames[False]), f"dial at {2.0 * k}, views kept: {cached}"
                culled_draws += sum(c.n > 0 for c in r._culled.values())
        assert culled_draws  # the needle-tip view left part of the skull out
    finally:
        app.close()

"""Live fluoroscopy keeps each mesh's share of the image: a pulse draws again only the meshes that
changed since the last (the needle), and the image and its edge-enhancement blur equal those made
from scratch in one pass."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from conftest import open_app

from chainsim.components.input_events import Widget
from chainsim.components.resources import PendingInput
from chainsim.game.render.radiograph import blurred
from chainsim.game.trainer.inputscript import load_script

ROOT = Path(__file__).resolve().parents[2]
PACK = ROOT / "assets" / "prp"


def test_live_pulses_redraw_only_the_needle_and_equal_a_fresh_image(gl_ctx):
    from chainsim.game.render.renderer import Renderer

    app = open_app(str(PACK))
    try:
        events = load_script(PACK / "scripts" / "correct.toml")
        last = max(t for t, _ in events)
        # the pedal held from after the landmarks to the end: the needle turns and goes in under it
        events += [(1.7, Widget("fluoro_live", True)), (last + 0.2, Widget("fluoro_live", False))]
        app.resource(PendingInput).extend(sorted(events, key=lambda e: e[0]))
        fr = app.resource(Renderer).fluoro
        drawn: list[int] = []  # triangles of each mesh drawn into an image
        inner = fr._draw

        def counting(meshes, vp, camera):
            drawn.extend(m.gpu.n_indices // 3 for m in meshes)
            return inner(meshes, vp, camera)

        fr._draw = counting
        poses, images, pose = 0, 0, None
        for _ in range(int((last + 0.3) / app.time.dt)):
            before = fr.image_id
            app.update(app.time.dt)
            if fr.image_id != before:
                images += 1
                if fr._pose != pose:
                    poses, pose = poses + 1, fr._pose
        skull = max(drawn)
        assert images >= 30  # 15 a second
        # the skull's share is made once per pose of the arm, not once per image
        assert drawn.count(skull) == poses < images / 5
        # the last image: as one pass over every mesh draws it, and its blur as the whole image's
        fresh = inner(
            [m for m in _meshes(app) if m.mu > 0 and m.gpu.n_indices], fr.camera.view_projection(1.0), fr.camera
        )
        assert np.allclose(fr.path, fresh, rtol=1e-5, atol=1e-3)
        assert np.allclose(fr.blur, blurred(fr.path), atol=1e-3)
    finally:
        app.close()


def _meshes(app):
    from chainsim.game.render.render_system import fluoro_draw

    with app.active():
        return fluoro_draw(app).meshes

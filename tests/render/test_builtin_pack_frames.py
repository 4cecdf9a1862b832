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
    from chainsim.systems.view import ViewState

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

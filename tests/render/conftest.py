"""Render tests run on one EGL context for the whole session (Mesa llvmpipe where there is no GPU).

They skip only when no EGL context can be made; the GL error flag is checked before and after each.
"""

from __future__ import annotations

import textwrap

import pytest


@pytest.fixture(scope="session")
def gl_ctx():
    from chainsim.game.render.context import GLUnavailable, egl_context

    try:
        return egl_context()
    except GLUnavailable as e:
        pytest.skip(f"no EGL OpenGL 3.3 context: {e}")


@pytest.fixture(autouse=True)
def gl_clean(gl_ctx):
    assert gl_ctx.error == "GL_NO_ERROR"
    yield gl_ctx
    assert gl_ctx.error == "GL_NO_ERROR"


HEADER = """
[pack]
name = "{name}"
format = 1

[settings]
window_size = [{w}.0, {h}.0]
background = [0.0, 0.0, 0.0, 1.0]
"""


@pytest.fixture
def make_pack(tmp_path):
    """Write a pack.toml (header + body) into a fresh folder; returns the folder as a string."""

    def make(body: str, name: str = "t", size=(320, 240)) -> str:
        root = tmp_path / name
        root.mkdir()
        text = HEADER.format(name=name, w=size[0], h=size[1]) + textwrap.dedent(body)
        (root / "pack.toml").write_text(text, encoding="utf-8")
        return str(root)

    return make


def open_app(ref: str, size=None):
    from chainsim.game.trainer.headless import build_app

    return build_app(ref, render=True, headless=True, size=size)


def frame_pixels(app, strip_overlay: bool = True):
    """Draw the world (optionally without panel/HUD/titles) and return (frame, RGBA image bottom-up)."""
    import numpy as np

    from chainsim.game.render.render_system import RenderTarget, collect_frame, sync_deformables
    from chainsim.game.render.renderer import Renderer

    target = app.resource(RenderTarget)
    with app.active():
        sync_deformables(app)
        frame = collect_frame(app)
        if strip_overlay:
            frame.panels, frame.hud, frame.labels = [], None, []
            for v in frame.views:
                v.title = ""
        app.resource(Renderer).render(frame, target.fbo)
    w, h = target.fbo.size
    img = np.frombuffer(target.fbo.read(components=4, alignment=1), np.uint8).reshape(h, w, 4)
    return frame, img

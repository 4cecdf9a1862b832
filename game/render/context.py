"""GL contexts: an EGL standalone context with an off-screen framebuffer, or the current window's.

EGL (Mesa llvmpipe on machines without a GPU) gives the same renderer without a display, for
`chainsim snapshot`, `run --screenshot-every` and the render tests.
"""

from __future__ import annotations

import moderngl

from chainsim.systems.engine.errors import UserError


class GLUnavailable(UserError):
    """No usable OpenGL 3.3 context (no EGL library or driver)."""


_shared: moderngl.Context | None = None


def egl_context() -> moderngl.Context:
    """The process-wide EGL context (created on first use; Apps share it and free their own objects)."""
    global _shared
    if _shared is not None:
        return _shared
    try:
        # moderngl's stub types each keyword setting as a dict; backend is a str
        ctx = moderngl.create_standalone_context(backend="egl", require=330)  # type: ignore[arg-type]
    except Exception as e:  # missing libEGL, no driver, too old GL
        raise GLUnavailable(
            f"off-screen rendering needs EGL with OpenGL 3.3 (e.g. Mesa's libegl1 and "
            f"libgl1-mesa-dri); it is not available here ({type(e).__name__}: {e})"
        ) from None
    _shared = ctx
    return ctx


def window_context() -> moderngl.Context:
    """A moderngl context on the GL context current in this thread (a pyglet window's)."""

    return moderngl.create_context(require=330)


def offscreen_framebuffer(ctx: moderngl.Context, size: tuple[int, int]) -> moderngl.Framebuffer:
    """RGBA8 colour + 24-bit depth, the size of a window in pixels."""
    w, h = max(int(size[0]), 1), max(int(size[1]), 1)
    color = ctx.renderbuffer((w, h), 4)
    depth = ctx.depth_renderbuffer((w, h))
    return ctx.framebuffer(color_attachments=[color], depth_attachment=depth)


def fbo_size(fbo: moderngl.Framebuffer) -> tuple[int, int]:
    """A framebuffer's (width, height) in pixels."""
    w, h = fbo.size
    return w, h


_parking: dict[int, moderngl.Framebuffer] = {}


def release_framebuffer(ctx: moderngl.Context, fbo: moderngl.Framebuffer) -> None:
    """Release a framebuffer without leaving it bound: moderngl re-binds the current framebuffer after
    creating another one, and binding a deleted one is a GL error."""
    if ctx.fbo is fbo:
        park = _parking.get(id(ctx))
        if park is None:
            park = _parking[id(ctx)] = ctx.framebuffer(color_attachments=[ctx.renderbuffer((1, 1), 4)])
        park.use()
    fbo.release()

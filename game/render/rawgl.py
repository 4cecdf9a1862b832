"""Copying a rectangle of one framebuffer into another (glBlitFramebuffer), which moderngl does not offer.

moderngl only blits whole framebuffers onto each other at the same place. A cached viewport image
(chainsim.game.render.viewcache) has to land at its view's rectangle, with its depth when items are drawn
over it. Drawn with a shader, that copy costs Mesa's software renderer about 2.3 ms for colour and
4.4 ms with depth on a 768 x 800 view; a blit between framebuffers of the same formats is a memory
copy there (0.3 ms). The entry points come from the system's GL library (GLVND's libOpenGL or
libGL), which dispatch to whatever context is current. A blit the GL refuses (formats that differ,
a multisampled window) is not tried again for that destination; the caller draws the copy instead.
"""

from __future__ import annotations

import ctypes
import ctypes.util

GL_READ_FRAMEBUFFER = 0x8CA8
GL_DRAW_FRAMEBUFFER = 0x8CA9
GL_FRAMEBUFFER = 0x8D40
GL_COLOR_BUFFER_BIT = 0x4000
GL_DEPTH_BUFFER_BIT = 0x0100
GL_NEAREST = 0x2600

_gl = None  # (bind, blit, get_error) once looked up; False when the library has none


def _entry_points():
    global _gl
    if _gl is None:
        _gl = False
        for name in ("libOpenGL.so.0", "libGL.so.1", ctypes.util.find_library("GL")):
            if not name:
                continue
            try:
                lib = ctypes.CDLL(name)
                bind, blit, err = lib.glBindFramebuffer, lib.glBlitFramebuffer, lib.glGetError
            except (OSError, AttributeError):
                continue
            bind.argtypes = [ctypes.c_uint, ctypes.c_uint]
            bind.restype = None
            blit.argtypes = [ctypes.c_int] * 8 + [ctypes.c_uint, ctypes.c_uint]
            blit.restype = None
            err.argtypes = []
            err.restype = ctypes.c_uint
            _gl = (bind, blit, err)
            break
    return _gl or None


class Blitter:
    """Rectangle copies between the framebuffers of one moderngl context."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.refused: set[tuple[int, bool]] = set()  # (destination glo, with depth) the GL refused

    def copy(self, src, dst, origin: tuple[int, int], size: tuple[int, int], at: tuple[int, int], depth: bool) -> bool:
        """Copy `src`'s rectangle (*origin, *size) to `dst` at `at` (colour, and depth with `depth`).
        False when it could not be done here (no entry points, or refused): nothing was changed."""
        gl = _entry_points()
        if gl is None or (dst.glo, depth) in self.refused:
            return False
        bind, blit, get_error = gl
        ctx = self.ctx
        for _ in range(8):  # errors of earlier calls are not this copy's (bounded: a lost context repeats one)
            if not get_error():
                break
        scissor = ctx.scissor
        ctx.scissor = None  # a scissored blit is drawn, an unscissored one copied
        sx, sy = origin
        w, h = size
        x, y = at
        bind(GL_READ_FRAMEBUFFER, src.glo)
        bind(GL_DRAW_FRAMEBUFFER, dst.glo)
        blit(
            sx,
            sy,
            sx + w,
            sy + h,
            x,
            y,
            x + w,
            y + h,
            GL_COLOR_BUFFER_BIT | (GL_DEPTH_BUFFER_BIT if depth else 0),
            GL_NEAREST,
        )
        ok = get_error() == 0
        bind(GL_FRAMEBUFFER, dst.glo)
        ctx.scissor = scissor
        if not ok:
            self.refused.add((dst.glo, depth))
        return ok

"""Cached 3-D viewports: a view is drawn into its own image only when something it shows changed,
and copied into the frame otherwise.

A window under a software renderer (Mesa llvmpipe) spends most of a frame rasterising the 3-D views
(`chainsim bench render --pack prp`). Most frames change only some of them - orbiting moves the
surgeon's view, not the needle-tip view; between actions nothing moves at all - so each view keeps
an image, drawn in the first frame in which the view has not changed (while it changes, as in a
drag, it is drawn straight into the frame, as an image would only add a copy), with a key of
everything that decides its pixels: rectangle, background, camera
matrix, and per mesh, marker, line, plane and label what it is, where and in which colour, plus the
mesh's upload count (`GpuMesh.version`). An equal key means equal pixels; the copy is exact
(texelFetch, one texel per pixel). Labels keep the visibility found when the image was drawn.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from chainsim.game.gl import shaders


def view_key(frame, view, r, clear) -> tuple:
    """Everything the view's pixels depend on, as a comparable tuple."""
    vp = np.asarray(view.camera.view_projection(r.aspect), np.float64)
    meshes = tuple(
        (
            m.gpu.serial,
            m.gpu.version,
            m.gpu.n_indices,
            np.asarray(m.model, np.float64).tobytes(),
            tuple(float(c) for c in m.color),
            m.wireframe,
            m.shading,
            m.entity,
        )
        for m in frame.meshes
    )
    markers = tuple(
        (np.asarray(p, np.float64).tobytes(), float(rad), tuple(float(c) for c in col), ent)
        for p, rad, col, ent in frame.markers
    )
    lines = tuple((np.asarray(p, np.float64).tobytes(), tuple(float(c) for c in col)) for p, col in frame.lines)
    planes = tuple((np.asarray(p, np.float64).tobytes(), tuple(float(c) for c in col)) for p, col in frame.planes)
    labels = tuple(np.asarray(p, np.float64).tobytes() for p, _t, _c in frame.labels)
    return (
        (r.w, r.h),
        tuple(float(c) for c in clear),
        vp.tobytes(),
        np.asarray(view.camera.eye, np.float64).tobytes(),
        view.hide_entity,
        meshes,
        markers,
        lines,
        planes,
        labels,
    )


@dataclass
class CachedView:
    fbo: object
    image: object
    size: tuple[int, int]
    key: tuple | None = None  # of the image
    last: tuple | None = None  # of the view in the last frame
    still: int = 0  # frames since the key last changed
    seen: list = field(default_factory=list)  # label visibility when the image was drawn


class ViewCache:
    """Images of the 3-D viewports by name, and the copy that puts one into the frame."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.views: dict[str, CachedView] = {}
        self.prog = ctx.program(vertex_shader=shaders.COPY_VS, fragment_shader=shaders.COPY_FS)
        quad = np.array([-1, -1, 1, -1, -1, 1, 1, 1], np.float32)
        self.vbo = ctx.buffer(quad.tobytes())
        self.vao = ctx.vertex_array(self.prog, [(self.vbo, "2f", "in_pos")])
        # statistics (tests, benchmarks): views drawn into their image, copied from it, drawn straight
        self.redrawn = 0
        self.reused = 0
        self.direct = 0

    def slot(self, name: str, size: tuple[int, int]) -> CachedView:
        """The view's image (re)made at `size` (pixels)."""
        cv = self.views.get(name)
        if cv is not None and cv.size == size:
            return cv
        if cv is not None:
            self._release(cv)
        image = self.ctx.texture(size, 4)
        fbo = self.ctx.framebuffer(color_attachments=[image], depth_attachment=self.ctx.depth_renderbuffer(size))
        cv = self.views[name] = CachedView(fbo, image, size)
        return cv

    def copy(self, cv: CachedView, r) -> None:
        """Put the image into rectangle `r` of the bound framebuffer (viewport and scissor set to it)."""
        ctx = self.ctx
        ctx.disable(ctx.DEPTH_TEST | ctx.BLEND | ctx.CULL_FACE)
        cv.image.use(0)
        self.prog["u_image"].value = 0
        self.prog["u_origin"].value = (r.x, r.y)
        self.vao.render(ctx.TRIANGLE_STRIP)

    def forget(self, keep: set[str]) -> None:
        """Drop the images of views no longer drawn."""
        for name in [n for n in self.views if n not in keep]:
            self._release(self.views.pop(name))

    def _release(self, cv: CachedView) -> None:
        for att in list(cv.fbo.color_attachments) + [cv.fbo.depth_attachment]:
            if att is not None:
                att.release()
        cv.fbo.release()

    def release(self) -> None:
        for cv in self.views.values():
            self._release(cv)
        self.views.clear()
        for o in (self.vao, self.vbo, self.prog):
            o.release()

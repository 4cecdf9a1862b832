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

import moderngl
import numpy as np

from chainsim.game.render import shaders
from chainsim.game.render.rawgl import Blitter


def base_key(frame, view, r, clear) -> tuple:
    """What a view's pixels depend on besides its items: rectangle, background, camera, hidden entity,
    how many items of each kind it has, and where the labels are."""
    vp = np.asarray(view.camera.view_projection(r.aspect), np.float64)
    labels = tuple(np.asarray(p, np.float64).tobytes() for p, _t, _c in frame.labels)
    counts = (len(frame.meshes), len(frame.markers), len(frame.lines), len(frame.planes))
    return (
        (r.w, r.h),
        tuple(float(c) for c in clear),
        vp.tobytes(),
        np.asarray(view.camera.eye, np.float64).tobytes(),
        view.hide_entity,
        counts,
        labels,
    )


def item_keys(frame) -> list[tuple]:
    """One key per drawn item - meshes, markers, lines, planes, in that order (`Item` numbering) - of
    what it is, where and in which colour, plus a mesh's upload count (`GpuMesh.version`)."""
    keys: list[tuple] = [
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
    ]
    keys += [
        (np.asarray(p, np.float64).tobytes(), float(rad), tuple(float(c) for c in col), ent)
        for p, rad, col, ent in frame.markers
    ]
    keys += [(np.asarray(p, np.float64).tobytes(), tuple(float(c) for c in col)) for p, col in frame.lines]
    keys += [(np.asarray(p, np.float64).tobytes(), tuple(float(c) for c in col)) for p, col in frame.planes]
    return keys


@dataclass
class CachedView:
    fbo: moderngl.Framebuffer
    image: moderngl.Texture
    size: tuple[int, int]
    depth: moderngl.Texture  # depth texture of `fbo` (copied with the image under a layer's live items)
    key: tuple | None = None  # of the image: a view key, or ("layer", base, live items, their keys) of a layer
    last: tuple | None = None  # of the view in the last frame
    still: int = 0  # frames since the key last changed
    seen: list = field(default_factory=list)  # label visibility when the image was drawn
    items: list = field(default_factory=list)  # item keys in the last frame
    age: list = field(default_factory=list)  # per item: frames since its key last changed
    over: tuple[moderngl.Framebuffer, moderngl.Texture] | None = (
        None  # layer with see-through items: (framebuffer, image) of the layer with them blended
    )
    layers: int = 0  # layers drawn (statistics: tests)


class ViewCache:
    """Images of the 3-D viewports by name, and the copies that put one into the frame."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.views: dict[str, CachedView] = {}
        self.prog = ctx.program(vertex_shader=shaders.COPY_VS, fragment_shader=shaders.COPY_FS)
        self.prog_depth = ctx.program(vertex_shader=shaders.COPY_VS, fragment_shader=shaders.COPY_DEPTH_FS)
        quad = np.array([-1, -1, 1, -1, -1, 1, 1, 1], np.float32)
        self.vbo = ctx.buffer(quad.tobytes())
        self.vao = ctx.vertex_array(self.prog, [(self.vbo, "2f", "in_pos")])
        self.vao_depth = ctx.vertex_array(self.prog_depth, [(self.vbo, "2f", "in_pos")])
        # statistics (tests, benchmarks): views drawn into their image, copied from it, drawn straight,
        # and frames of a view made from a layer image and its live items
        self.redrawn = 0
        self.reused = 0
        self.direct = 0
        self.layered = 0
        self.blitter = Blitter(ctx)
        self.blits = 0  # copies done by blitting rather than drawing

    def slot(self, name: str, size: tuple[int, int]) -> CachedView:
        """The view's image (re)made at `size` (pixels)."""
        cv = self.views.get(name)
        if cv is not None and cv.size == size:
            return cv
        if cv is not None:
            self._release(cv)
        image = self.ctx.texture(size, 4)
        depth = self.ctx.depth_texture(size)
        depth.compare_func = ""  # read as values (texelFetch), not as a shadow map
        fbo = self.ctx.framebuffer(color_attachments=[image], depth_attachment=depth)
        cv = self.views[name] = CachedView(fbo, image, size, depth)
        return cv

    def over(self, cv: CachedView) -> tuple[moderngl.Framebuffer, moderngl.Texture]:
        """The second image of a layer with see-through items: (framebuffer, image), made on first use."""
        if cv.over is None:
            image = self.ctx.texture(cv.size, 4)
            depth = self.ctx.depth_renderbuffer(cv.size)  # the layer's depth, for the see-through pass
            cv.over = (self.ctx.framebuffer(color_attachments=[image], depth_attachment=depth), image)
        return cv.over

    def copy(self, cv: CachedView, r, depth: bool = False, image=None, box=None) -> None:
        """Put the image (or the layer's see-through `image`) into rectangle `r` of the bound framebuffer
        (viewport and scissor set to it), or only its part in `box` (x, y, w, h, framebuffer pixels);
        with `depth`, the image's depth too, so what is drawn next is hidden behind it."""
        ctx = self.ctx
        bx, by, bw, bh = box or (r.x, r.y, r.w, r.h)
        src = cv.fbo if image is None else self.over(cv)[0]  # `image` is the second image's: it is made
        if self.blitter.copy(src, ctx.fbo, (bx - r.x, by - r.y), (bw, bh), (bx, by), depth):
            self.blits += 1
            return
        scissor = ctx.scissor
        ctx.scissor = (bx, by, bw, bh)
        ctx.disable(ctx.BLEND | ctx.CULL_FACE)
        (image or cv.image).use(0)
        if depth:
            cv.depth.use(1)
            self.prog_depth["u_image"].value = 0
            self.prog_depth["u_depth"].value = 1
            self.prog_depth["u_origin"].value = (r.x, r.y)
            ctx.enable(ctx.DEPTH_TEST)
            ctx.depth_func = "1"  # always: the copy writes every depth
            ctx.fbo.depth_mask = True
            self.vao_depth.render(ctx.TRIANGLE_STRIP)
            ctx.depth_func = "<"
        else:
            ctx.disable(ctx.DEPTH_TEST)
            self.prog["u_image"].value = 0
            self.prog["u_origin"].value = (r.x, r.y)
            self.vao.render(ctx.TRIANGLE_STRIP)
        ctx.scissor = scissor

    def forget(self, keep: set[str]) -> None:
        """Drop the images of views no longer drawn."""
        for name in [n for n in self.views if n not in keep]:
            self._release(self.views.pop(name))

    def _release(self, cv: CachedView) -> None:
        fbos = [cv.fbo] + ([cv.over[0]] if cv.over is not None else [])
        for fbo in fbos:
            for att in list(fbo.color_attachments) + [fbo.depth_attachment]:
                if att is not None:
                    att.release()
            fbo.release()

    def release(self) -> None:
        for cv in self.views.values():
            self._release(cv)
        self.views.clear()
        for o in (self.vao, self.vao_depth, self.vbo, self.prog, self.prog_depth):
            o.release()

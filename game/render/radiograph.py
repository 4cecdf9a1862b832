"""The C-arm's radiograph: X-ray attenuation through closed meshes, and its display (thesis 3.2.3).

A radiograph records, for each ray from the X-ray source to a detector pixel, how much of the beam
got through: I / I0 = exp(-L) with L the line integral of the linear attenuation coefficient mu
along the ray (Beer-Lambert). With the anatomy made of closed surfaces, each of one material, L is
a sum over those surfaces of mu times the length of the ray inside them, and that length is the
sum of the distances from the source to where the ray leaves a surface minus the sum of the
distances to where it enters one. A triangle faces the source where the ray enters (its outward
normal points back at the source), so one additive pass does it: every fragment of every mesh adds
mu * distance(source, fragment), negated for front faces, into a 32-bit float target (blending ONE,
ONE; no depth test, no culling; GL's rasterisation rules cover each pixel centre once per surface
crossing, so a closed mesh contributes exactly its chord). The camera is the C-arm's cone beam: the
eye at the source, the round detector's cone as the field of view (chainsim.systems.view.ui.viewports.carm_camera).

Display: L is shown on a logarithmic (linear-in-L) scale, bright where the beam got through and
dark where it did not, as a fluoroscopy monitor shows it: air light, soft tissue grey, bone darker,
the steel needle black. Edges are enhanced (L plus its difference from a blurred copy), as a
fluoroscopy chain's image processing does, and the grey window follows the body in the image the
way a C-arm's automatic brightness control does (from the 1st to the 98th percentile of L where the
beam crossed tissue), so a lateral and a submental image both show bone detail; outside the round
field the image is black.

The image is made only when the C-arm says so (a new `CArm.image_id`: a shot, or a pulse of live
fluoroscopy) and then shown unchanged - frozen - until the next one, whatever the needle does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from chainsim.game.render.context import release_framebuffer
from chainsim.game.render.meshbuf import GpuMesh
from chainsim.systems.view.ui.viewports import Camera, Rect

IMAGE_PX = 512
#: a view shown larger than LARGE_VIEW_PX framebuffer pixels a side gets images of LARGE_IMAGE_PX
LARGE_VIEW_PX = 560
LARGE_IMAGE_PX = 1024


def image_size(view_side_px: float) -> int:
    """The side of the images made for a C-arm view of this many framebuffer pixels a side."""
    return LARGE_IMAGE_PX if view_side_px > LARGE_VIEW_PX else IMAGE_PX


#: edge enhancement: gain and blur radius (pixels of a IMAGE_PX image)
EDGE_GAIN = 1.0
EDGE_SIGMA_PX = 6.0
#: attenuation below this is air around the head, left out of the grey window
AIR_L = 0.3

ACC_VS = """
#version 330
uniform mat4 u_mvp;
uniform mat4 u_model;
in vec3 in_pos;
out vec3 v_world;
void main() {
    gl_Position = u_mvp * vec4(in_pos, 1.0);
    v_world = (u_model * vec4(in_pos, 1.0)).xyz;
}
"""

ACC_FS = """
#version 330
uniform vec3 u_source;
uniform float u_mu;
in vec3 v_world;
out float f_path;
void main() {
    // leaving a surface adds mu * distance, entering one subtracts it: the sum is mu * chord
    float d = distance(v_world, u_source);
    f_path = gl_FrontFacing ? -u_mu * d : u_mu * d;
}
"""

SHOW_VS = """
#version 330
in vec2 in_xy;
out vec2 v_uv;
void main() {
    v_uv = in_xy * 0.5 + 0.5;
    gl_Position = vec4(in_xy, 0.0, 1.0);
}
"""

SHOW_FS = """
#version 330
uniform sampler2D u_image;
in vec2 v_uv;
out vec4 f_color;
void main() { f_color = vec4(texture(u_image, v_uv).rgb, 1.0); }
"""


@dataclass(slots=True)
class XrayMesh:
    """One closed mesh in the beam: its GPU buffers, model matrix and attenuation (1/mm)."""

    gpu: GpuMesh
    model: np.ndarray
    mu: float


@dataclass(slots=True)
class FluoroDraw:
    """What the C-arm view needs this frame (gathered by chainsim.game.render.render_system)."""

    camera: Camera  # the pose of the image to make (the C-arm's at its last shot or pulse)
    image_id: int
    meshes: list[XrayMesh] = field(default_factory=list)
    status: str = ""  # one line under the view's title: projection, images, exposure
    live: bool = False
    attempt: int = 0  # the procedure attempt the C-arm counts for; a new one starts with no image
    images: int = 0  # images this attempt (shots, and live pulses)
    window: float = 1.0  # the monitor's window width, times the automatic one
    level: float = 0.0  # its centre, moved by this fraction of the automatic width (+: the image lighter)
    size: int = IMAGE_PX  # pixels a side of the images made now (larger while the view is shown large)


def _mat(m: np.ndarray) -> bytes:
    return np.asarray(m, np.float32).T.tobytes()


def blur_sigma(side: int) -> float:
    """The edge enhancement's blur, in pixels of an image `side` pixels a side."""
    return EDGE_SIGMA_PX * side / IMAGE_PX


def blurred(path: np.ndarray) -> np.ndarray:
    """The blurred copy of L that the edge enhancement subtracts (scipy's gaussian, reflected at the edges)."""
    from scipy import ndimage  # noqa: PLC0415 - half a second to import: the window loads it behind its first picture

    return ndimage.gaussian_filter(path, blur_sigma(path.shape[0]))


def blurred_part(part: np.ndarray) -> np.ndarray:
    """`blurred(part)` for one mesh's share of L, made only around where that share is not zero: a
    needle covers a few thousand pixels of the image, and the blur is a sum, so the blur of the
    whole is the sum of its parts' blurs."""
    rows, cols = np.flatnonzero(part.any(axis=1)), np.flatnonzero(part.any(axis=0))
    out = np.zeros_like(part)
    if not rows.size:
        return out
    sigma = blur_sigma(part.shape[0])
    pad = int(4.0 * sigma + 0.5) + 1  # scipy truncates the kernel at 4 sigma: nothing reaches further
    y0, y1, x0, x1 = rows[0] - pad, rows[-1] + 1 + pad, cols[0] - pad, cols[-1] + 1 + pad
    h, w = part.shape
    if y0 < 0 or x0 < 0 or y1 > h or x1 > w:  # near the edge the reflection matters: the whole image
        return blurred(part)
    from scipy import ndimage  # noqa: PLC0415 - as in blurred

    # zeros all round the crop, at least the kernel's reach: its reflected edges add nothing
    out[y0:y1, x0:x1] = ndimage.gaussian_filter(part[y0:y1, x0:x1], sigma)
    return out


_FIELDS: dict[tuple[int, int], np.ndarray] = {}


def round_field(h: int, w: int) -> np.ndarray:
    """The detector's round field: True inside (one mask per image size, made once)."""
    inside = _FIELDS.get((h, w))
    if inside is None:
        yy, xx = np.mgrid[0:h, 0:w]
        r = 0.5 * min(h, w)
        inside = _FIELDS[(h, w)] = (xx + 0.5 - w / 2) ** 2 + (yy + 0.5 - h / 2) ** 2 <= (r - 1.0) ** 2
    return inside


def grey(path: np.ndarray, window: float = 1.0, level: float = 0.0, blur: np.ndarray | None = None) -> np.ndarray:
    """Attenuation L (H, W) -> display grey (H, W) uint8: linear in L, bright = little attenuation,
    windowed over the round field by percentiles (automatic brightness), black outside the field.
    `window` narrows (< 1) or widens the grey window about its centre, `level` moves the centre by
    that fraction of the automatic width, as a monitor's window/level controls do. `blur`, when
    given, is `blurred(path)` already made."""
    h, w = path.shape
    inside = round_field(h, w)
    # edge enhancement, as a fluoroscopy chain applies it: the image plus part of its detail above a blur
    sharp = path + EDGE_GAIN * (path - (blurred(path) if blur is None else blur))
    vals = sharp[inside & (path > AIR_L)]  # the window follows the body, not the air around it
    lo, hi = np.percentile(vals, [1.0, 98.0]) if vals.size else (0.0, 1.0)
    lo = min(lo, 0.0)
    if hi - lo < 1e-6:
        hi = lo + 1.0
    if window != 1.0 or level != 0.0:
        mid, half = 0.5 * (lo + hi) + level * (hi - lo), 0.5 * (hi - lo) * max(window, 1e-3)
        lo, hi = mid - half, mid + half
    v = 1.0 - np.clip((sharp - lo) / (hi - lo), 0.0, 1.0)
    out = np.where(inside, 0.06 + 0.9 * v, 0.0)
    return np.round(out * 255.0).astype(np.uint8)


class FluoroRenderer:
    """Makes C-arm images (float attenuation images) and draws the latest one into a viewport."""

    def __init__(self, ctx, size: int = IMAGE_PX):
        self.ctx = ctx
        self.size = int(size)
        self.acc = ctx.program(vertex_shader=ACC_VS, fragment_shader=ACC_FS)
        self.show = ctx.program(vertex_shader=SHOW_VS, fragment_shader=SHOW_FS)
        self.target = ctx.texture((self.size, self.size), 1, dtype="f4")
        self.fbo = ctx.framebuffer(color_attachments=[self.target])
        self.display = ctx.texture((self.size, self.size), 4)
        self.display.filter = (ctx.LINEAR, ctx.LINEAR)
        quad = np.array([-1, -1, 1, -1, -1, 1, 1, 1], np.float32)
        self.quad = ctx.buffer(quad.tobytes())
        self.quad_vao = ctx.vertex_array(self.show, [(self.quad, "2f", "in_xy")])
        self.image_id = -1  # the last image made; -1 before the first
        self.shown = False  # whether it is on the view (a new attempt clears the last attempt's image)
        self.attempt = 0
        self.path: np.ndarray | None = None  # attenuation L of the image shown, rows top first
        self.camera: Camera | None = None  # its C-arm pose
        self.contrast = (1.0, 0.0)  # the window/level the display texture was made with
        self.blur: np.ndarray | None = None  # blurred(self.path), kept with it
        self._pose: tuple | None = None  # the arm's pose and image size the kept shares were made for
        self._parts: dict = {}  # mesh key -> (its share of L, that share's blur) (see capture)
        # In the window a single image is made one frame after the shot, once a frame saying so has been
        # drawn: making it takes a software renderer a good part of a second at full-window size, and
        # a trainee who pressed x sees the cue at once instead of a frozen window. Off screen (tests,
        # snapshots, replays) the image is made at the shot itself.
        self.defer_shots = False
        self.waiting = 0  # the image the view announces and has not made yet (0: none)
        self.cue_drawn = 0  # the last image whose cue a drawn frame has shown

    def capture(self, meshes: list[XrayMesh], camera: Camera) -> np.ndarray:
        """Attenuation image (size x size, float32, rows top first) of `meshes` seen by `camera`.

        L is a sum over meshes, so each mesh's share is kept with what it was made from (the arm's
        pose, the mesh's GPU version, its model matrix, its attenuation) and only shares whose mesh
        changed are drawn again: in live fluoroscopy that is the needle, a few hundred triangles,
        not the skull's two hundred thousand (which cost llvmpipe some 50 ms an image). Each share's
        blur is kept as well (`self.blur`), for the same reason."""
        vp = camera.view_projection(1.0)
        pose = (vp.tobytes(), tuple(float(c) for c in camera.eye), self.size)
        if pose != self._pose:
            self._parts.clear()
            self._pose = pose
        total = np.zeros((self.size, self.size), np.float32)
        blur = np.zeros((self.size, self.size), np.float32)
        kept = {}
        for m in meshes:
            if m.mu <= 0.0 or not m.gpu.n_indices:
                continue
            model = np.asarray(m.model, float)
            key = (m.gpu.serial, m.gpu.version, m.gpu.n_indices, model.tobytes(), float(m.mu))
            part = self._parts.get(key)
            if part is None:
                share = self._draw([m], vp, camera)
                part = (share, blurred_part(share))
            kept[key] = part
            total += part[0]
            blur += part[1]
        self._parts = kept  # shares of meshes gone or changed are dropped
        self.blur = blur
        return total

    def _draw(self, meshes: list[XrayMesh], vp: np.ndarray, camera: Camera) -> np.ndarray:
        """The attenuation of `meshes` alone (rows top first), drawn in one additive pass."""
        ctx = self.ctx
        try:
            self.fbo.use()
            ctx.scissor = None
            ctx.viewport = (0, 0, self.size, self.size)
            self.fbo.clear(0.0, 0.0, 0.0, 0.0)
            ctx.disable(ctx.DEPTH_TEST | ctx.CULL_FACE)
            ctx.enable(ctx.BLEND)
            ctx.blend_func = ctx.ONE, ctx.ONE
            ctx.blend_equation = ctx.FUNC_ADD
            self.acc["u_source"].value = tuple(float(c) for c in camera.eye)
            for m in meshes:
                model = np.asarray(m.model, float)
                self.acc["u_mvp"].write(_mat(vp @ model))
                if "u_model" in self.acc:
                    self.acc["u_model"].write(_mat(model))
                self.acc["u_mu"].value = float(m.mu)
                m.gpu.vao(self.acc, "tri").render(ctx.TRIANGLES, vertices=m.gpu.n_indices)
            raw = np.frombuffer(self.target.read(), np.float32).reshape(self.size, self.size)
        finally:
            ctx.disable(ctx.BLEND)
            ctx.blend_func = ctx.SRC_ALPHA, ctx.ONE_MINUS_SRC_ALPHA
        # the image's framebuffer stays bound: whoever draws next binds its own target first
        return np.ascontiguousarray(raw[::-1])

    def update(self, draw: FluoroDraw) -> bool:
        """Make a new image if the C-arm took one since the last; True when it did. A new attempt with
        no image of its own yet shows none (its caption says 0 images), not the last attempt's."""
        if draw.attempt != self.attempt:
            self.attempt = draw.attempt
            if draw.images == 0 and draw.image_id == self.image_id:
                self.shown, self.path, self.blur = False, None, None
        contrast = (draw.window, draw.level)
        if draw.image_id == self.image_id or draw.image_id <= 0:  # no new image (0: none taken yet)
            if self.path is not None and contrast != self.contrast:  # the monitor's window/level turned
                self._show(self.path, contrast)
            return False
        if self.defer_shots and not draw.live and self.cue_drawn != draw.image_id:
            self.waiting = draw.image_id  # drawn with its cue first (see __init__)
            return False
        self.waiting = 0
        if draw.size != self.size:
            self._resize(draw.size)
        path = self.capture(draw.meshes, draw.camera)
        self.path, self.camera, self.image_id, self.shown = path, draw.camera, draw.image_id, True
        self._show(path, contrast)
        return True

    def _show(self, path: np.ndarray, contrast: tuple[float, float]) -> None:
        """Show the image of attenuation `path` (the one kept in self.path) at window/level `contrast`."""
        g = grey(path, *contrast, blur=self.blur)
        if g.shape[0] != self.display.size[1]:
            self.display.release()
            self.display = self.ctx.texture((g.shape[1], g.shape[0]), 4)
            self.display.filter = (self.ctx.LINEAR, self.ctx.LINEAR)
        rgba = np.dstack([g, g, g, np.full_like(g, 255)])
        self.display.write(np.ascontiguousarray(rgba[::-1]).tobytes())  # GL rows bottom first
        self.contrast = contrast

    def _resize(self, size: int) -> None:
        """Make images of `size` pixels a side from now on (the one shown stays until the next)."""
        release_framebuffer(self.ctx, self.fbo)
        self.target.release()
        self.size = int(size)
        self.target = self.ctx.texture((self.size, self.size), 1, dtype="f4")
        self.fbo = self.ctx.framebuffer(color_attachments=[self.target])
        self._parts.clear()

    def draw(self, r: Rect) -> None:
        """The latest image, square and centred in the framebuffer rectangle `r` (black around it)."""
        if not self.shown or r.w <= 0 or r.h <= 0:
            return
        ctx = self.ctx
        side = min(r.w, r.h)
        x0, y0 = r.x + (r.w - side) // 2, r.y + (r.h - side) // 2
        ctx.viewport = (x0, y0, side, side)
        ctx.disable(ctx.DEPTH_TEST | ctx.BLEND | ctx.CULL_FACE)
        self.display.use(location=0)
        self.show["u_image"].value = 0
        self.quad_vao.render(ctx.TRIANGLE_STRIP)
        ctx.viewport = (r.x, r.y, r.w, r.h)

    def image_rgb(self) -> np.ndarray | None:
        """The image shown, as grey RGB (rows top first), or None before the first."""
        if self.path is None:
            return None
        g = grey(self.path, *self.contrast, blur=self.blur)
        return np.dstack([g, g, g])

    def release(self) -> None:
        release_framebuffer(self.ctx, self.fbo)  # parks the binding first if it is the bound one
        for o in (self.quad_vao, self.quad, self.target, self.display, self.acc, self.show):
            o.release()

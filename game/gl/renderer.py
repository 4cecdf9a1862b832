"""The frame renderer: every viewport of a layout, the control panel and the HUD, in one framebuffer.

Per 3-D viewport (thesis 3.3.4: global view, needle-tip view; 5.3 Figs 5.6-5.8: wireframe and shaded
deformation): clear its rectangle, then draw opaque meshes, wireframes (the ChainMail links), markers
and poly-lines with depth testing; then transparent meshes and planes sorted back to front with depth
writes off, each drawn back faces first and front faces second, so a see-through skin over a skull
blends in the right order. Panels and the HUD are drawn last in window pixels (`Overlay`).

The renderer only sees plain data (`Frame`); `chainsim.game.gl.render_system` gathers it from the world.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import trimesh

from chainsim.game.gl import shaders
from chainsim.game.gl.context import release_framebuffer
from chainsim.game.gl.meshbuf import GpuMesh
from chainsim.game.gl.overlay import Overlay
from chainsim.systems.ui.viewports import Camera, Rect
from chainsim.systems.ui.widgets import TITLE_PX, below_widgets

SHADING = {"smooth": 0, "flat": 1, "unlit": 2}
PANEL_BG = (0.13, 0.14, 0.17, 1.0)
TEXT = (0.92, 0.93, 0.95, 1.0)
DIM = (0.55, 0.57, 0.62, 1.0)
ACCENT = (0.30, 0.62, 0.95, 1.0)
LIGHT_RGBA = {"red": (0.92, 0.18, 0.16, 1.0), "green": (0.20, 0.85, 0.30, 1.0), "off": (0.30, 0.30, 0.32, 1.0)}


@dataclass(slots=True)
class MeshDraw:
    gpu: GpuMesh
    model: np.ndarray  # 4 x 4
    color: tuple  # RGBA, alpha = opacity
    wireframe: bool = False
    shading: str = "smooth"
    entity: int = -1


@dataclass(slots=True)
class ViewDraw:
    name: str
    kind: str
    rect: Rect  # window pixels
    camera: Camera | None
    title: str = ""
    clear: tuple | None = None  # RGBA; None: the frame background (3-D) or the panel colour
    hide_entity: int = -1  # not drawn in this view (an attached camera's own entity)


@dataclass(slots=True)
class PanelDraw:
    name: str
    rect: Rect
    title: str
    placed: list  # chainsim.systems.ui.widgets.Placed
    values: dict
    disabled: set
    hint: str = ""  # help of the widget under the pointer, shown at the bottom


@dataclass(slots=True)
class Frame:
    size: tuple[int, int]  # window pixels
    scale: float = 1.0  # framebuffer pixels per window pixel (HiDPI)
    background: tuple = (0.08, 0.09, 0.11, 1.0)
    views: list[ViewDraw] = field(default_factory=list)
    meshes: list[MeshDraw] = field(default_factory=list)
    lines: list[tuple] = field(default_factory=list)  # (points (K, 3), RGBA)
    markers: list[tuple] = field(default_factory=list)  # (position, radius, RGBA, entity)
    planes: list[tuple] = field(default_factory=list)  # (corners (4, 3), RGBA)
    labels: list[tuple] = field(default_factory=list)  # (position, text, RGBA)
    panels: list[PanelDraw] = field(default_factory=list)
    hud: Any = None  # chainsim.components.hud.HudState
    hud_view: str = ""  # viewport that shows the step text and messages
    help: list[str] | None = None  # shown centred when not None
    doc: tuple[str, str, int] | None = None  # (title, markdown text, first line) of an open docs page


def _mat(m: np.ndarray) -> bytes:
    return np.asarray(m, np.float32).T.tobytes()  # GLSL reads column-major


def _set(prog, name: str, value) -> None:
    """Set a uniform if the compiler kept it (unused ones are optimised away)."""
    if name in prog:
        u = prog[name]
        if isinstance(value, bytes):
            u.write(value)
        else:
            u.value = value


def icosphere(subdiv: int = 2) -> tuple[np.ndarray, np.ndarray]:

    s = trimesh.creation.icosphere(subdivisions=subdiv, radius=1.0)
    return np.asarray(s.vertices), np.asarray(s.faces)


class Renderer:
    """Draws `Frame`s into a framebuffer; owns the GPU meshes (by key) and GL programs."""

    def __init__(self, ctx):
        self.ctx = ctx
        self.mesh_prog = ctx.program(vertex_shader=shaders.MESH_VS, fragment_shader=shaders.MESH_FS)
        self.line_prog = ctx.program(vertex_shader=shaders.LINE_VS, fragment_shader=shaders.LINE_FS)
        self.id_prog = ctx.program(vertex_shader=shaders.MESH_VS, fragment_shader=shaders.ID_FS)
        self.meshes: dict[Any, GpuMesh] = {}
        sv, sf = icosphere()
        self.sphere = GpuMesh(ctx, sv, sf)
        self.dyn = ctx.buffer(reserve=1 << 14, dynamic=True)
        self.dyn_vao = ctx.vertex_array(self.line_prog, [(self.dyn, "3f", "in_pos")])
        self.overlay = Overlay(ctx)

    # -- meshes ------------------------------------------------------------------------------
    def mesh(self, key, vertices: np.ndarray, triangles: np.ndarray, links: np.ndarray | None = None) -> GpuMesh:
        """The GPU mesh for `key`, created from the arrays on first use."""
        gm = self.meshes.get(key)
        if gm is None or gm.n != len(vertices):
            if gm is not None:
                gm.release()
            gm = self.meshes[key] = GpuMesh(self.ctx, vertices, triangles, links)
        return gm

    def forget(self, key) -> None:
        gm = self.meshes.pop(key, None)
        if gm is not None:
            gm.release()

    # -- frame -------------------------------------------------------------------------------
    def render(self, frame: Frame, fbo, size: tuple[int, int] | None = None) -> None:
        """Draw `frame` into `fbo` (`size`: its pixel size when the framebuffer cannot tell, e.g. a
        resized window's default framebuffer)."""
        ctx = self.ctx
        fbo.use()
        W, H = size or fbo.size
        s = frame.scale
        ctx.scissor = None
        ctx.viewport = (0, 0, W, H)
        covered = sum(v.rect.scaled(s).w * v.rect.scaled(s).h for v in frame.views)
        if covered < W * H:  # viewports clear their own rectangles; clear the rest only when some shows
            fbo.clear(*frame.background, depth=1.0)
        for view in frame.views:
            r = view.rect.scaled(s)
            if r.w <= 0 or r.h <= 0:
                continue
            clear = view.clear or (PANEL_BG if view.kind == "panel" else frame.background)
            ctx.scissor = (r.x, r.y, r.w, r.h)
            ctx.viewport = (r.x, r.y, r.w, r.h)
            fbo.clear(*clear, depth=1.0, viewport=(r.x, r.y, r.w, r.h))
            if view.camera is not None and view.kind != "panel":
                self._scene(frame, view.camera, r, fbo, view.hide_entity)
        ctx.scissor = None
        ctx.viewport = (0, 0, W, H)
        self.overlay.set_scale(s)
        self._overlay(frame)
        self.overlay.flush((W, H))
        ctx.disable(ctx.BLEND)

    def _mesh_uniforms(self, prog, vp: np.ndarray, m: MeshDraw, eye) -> None:
        model = np.asarray(m.model, float)
        _set(prog, "u_mvp", _mat(vp @ model))
        _set(prog, "u_model", _mat(model))
        lin = model[:3, :3]
        det = np.linalg.det(lin)
        nm = np.linalg.inv(lin).T if abs(det) > 1e-30 else np.eye(3)
        _set(prog, "u_normal_mat", _mat(nm))
        _set(prog, "u_color", tuple(float(c) for c in m.color))
        _set(prog, "u_eye", tuple(float(c) for c in eye))
        _set(prog, "u_shading", SHADING.get(m.shading, 0))

    def _draw_mesh(self, m: MeshDraw, vp, eye) -> None:
        if m.wireframe:
            _set(self.line_prog, "u_mvp", _mat(vp @ np.asarray(m.model, float)))
            _set(self.line_prog, "u_color", tuple(float(c) for c in m.color))
            vao = m.gpu.vao(self.line_prog, "line")
            if m.gpu.n_line_indices:
                vao.render(self.ctx.LINES, vertices=m.gpu.n_line_indices)
        else:
            self._mesh_uniforms(self.mesh_prog, vp, m, eye)
            if m.gpu.n_indices:
                m.gpu.vao(self.mesh_prog, "tri").render(self.ctx.TRIANGLES, vertices=m.gpu.n_indices)

    def _dyn_draw(self, pts: np.ndarray, mode, vp, color) -> None:
        data = np.ascontiguousarray(pts, np.float32).tobytes()
        if len(data) > self.dyn.size:
            self.dyn.orphan(len(data) * 2)
        self.dyn.write(data)
        _set(self.line_prog, "u_mvp", _mat(vp))
        _set(self.line_prog, "u_color", tuple(float(c) for c in color))
        self.dyn_vao.render(mode, vertices=len(pts))

    def _scene(self, frame: Frame, cam: Camera, r: Rect, fbo, hide: int = -1) -> None:
        ctx = self.ctx
        vp = cam.view_projection(r.aspect)
        eye = np.asarray(cam.eye, float)
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.BLEND | ctx.CULL_FACE)
        fbo.depth_mask = True
        see_through = []
        for m in frame.meshes:
            if hide >= 0 and m.entity == hide:
                continue
            if m.color[3] < 0.999:
                see_through.append(("mesh", m))
            else:
                self._draw_mesh(m, vp, eye)
        for pos, radius, color, ent in frame.markers:
            if hide >= 0 and ent == hide:
                continue
            md = MeshDraw(self.sphere, _trs(pos, radius), color, entity=ent)
            if color[3] < 0.999:
                see_through.append(("mesh", md))
            else:
                self._draw_mesh(md, vp, eye)
        for pts, color in frame.lines:
            if len(pts) >= 2:
                self._dyn_draw(pts, ctx.LINE_STRIP, vp, color)
        for corners, color in frame.planes:
            see_through.append(("plane", (np.asarray(corners, float), color)))
        if not see_through:
            return

        def depth(item):
            kind, obj = item
            if kind == "plane":
                c = obj[0].mean(axis=0)
            else:
                c = (np.asarray(obj.model, float) @ np.r_[obj.gpu.center(), 1.0])[:3]
            return -float(np.linalg.norm(c - eye))

        see_through.sort(key=depth)  # farthest first
        ctx.enable(ctx.BLEND)
        ctx.blend_func = ctx.SRC_ALPHA, ctx.ONE_MINUS_SRC_ALPHA
        fbo.depth_mask = False
        for kind, obj in see_through:
            if kind == "plane":
                corners, color = obj
                self._dyn_draw(corners[[0, 1, 2, 0, 2, 3]], ctx.TRIANGLES, vp, color)
            elif obj.wireframe:
                self._draw_mesh(obj, vp, eye)
            else:
                ctx.enable(ctx.CULL_FACE)
                for face in ("front", "back"):  # back faces first, then the front ones over them
                    ctx.cull_face = face
                    self._draw_mesh(obj, vp, eye)
                ctx.disable(ctx.CULL_FACE)
        fbo.depth_mask = True
        ctx.disable(ctx.BLEND)

    # -- id pass (tests, GPU picking) ----------------------------------------------------------
    def id_image(self, frame: Frame, view_name: str, size: tuple[int, int]):
        """What each framebuffer pixel of a viewport shows: (entity (H, W) with -1 for none, triangle (H, W)).

        Triangle ids are indices into the mesh's triangle list (cut triangles accounted for). Rows
        are bottom-up (GL order), so [y, x] indexes framebuffer pixel (x, y)."""
        ctx = self.ctx
        view = next(v for v in frame.views if v.name == view_name)
        r = view.rect.scaled(frame.scale)
        W, H = size
        previous = ctx.fbo
        fbo = ctx.framebuffer(
            color_attachments=[ctx.renderbuffer((W, H), 4)], depth_attachment=ctx.depth_renderbuffer((W, H))
        )
        try:
            fbo.use()
            ctx.scissor = (r.x, r.y, r.w, r.h)
            ctx.viewport = (r.x, r.y, r.w, r.h)
            fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
            ctx.enable(ctx.DEPTH_TEST)
            ctx.disable(ctx.BLEND | ctx.CULL_FACE)
            vp = view.camera.view_projection(r.aspect)
            solid = [m for m in frame.meshes if not m.wireframe]
            for slot, m in enumerate(solid[:254]):
                _set(self.id_prog, "u_mvp", _mat(vp @ np.asarray(m.model, float)))
                _set(self.id_prog, "u_slot", slot + 1)
                if m.gpu.n_indices:
                    m.gpu.vao(self.id_prog, "tri").render(ctx.TRIANGLES, vertices=m.gpu.n_indices)
            raw = np.frombuffer(fbo.read(components=4, alignment=1), np.uint8).reshape(H, W, 4).astype(np.int64)
        finally:
            ctx.scissor = None
            if previous is not None:
                previous.use()
            release_framebuffer(ctx, fbo)
        slot = raw[:, :, 3]
        prim = raw[:, :, 0] | (raw[:, :, 1] << 8) | (raw[:, :, 2] << 16)
        ent = np.full((H, W), -1, np.int64)
        tri = np.full((H, W), -1, np.int64)
        for k, m in enumerate(solid[:254]):
            sel = slot == k + 1
            ent[sel] = m.entity
            tri[sel] = m.gpu.tri_ids[prim[sel] - 1]
        return ent, tri

    # -- 2-D ---------------------------------------------------------------------------------
    def _overlay(self, frame: Frame) -> None:
        ov = self.overlay
        s = frame.scale
        f = ov.font
        for view in frame.views:
            r = view.rect.scaled(s)
            if view.kind == "panel" or r.w <= 0:
                continue
            if view.title:
                w = f.width(view.title) + 12 * s
                ov.rect(r.x, r.y + r.h - f.line_h - 6 * s, w, f.line_h + 6 * s, (0, 0, 0, 0.45))
                ov.label(view.title, r.x + 6 * s, r.y + r.h - f.ascent - 3 * s, DIM)
            if view.camera is not None:
                for pos, text, color in frame.labels:
                    x, y, z = view.camera.project(pos, r)[0]
                    if -1 < z < 1 and r.contains(x, y):
                        ov.label(text, x + 4 * s, y + 4 * s, color)
            if frame.hud is not None and view.name == frame.hud_view:
                self._hud(frame.hud, r, s)
        for p in frame.panels:
            self._panel(p, frame.hud, s)
        if frame.doc is not None:
            self._doc(frame, s)
        if frame.help is not None:
            lines = frame.help
            W, H = frame.size[0] * s, frame.size[1] * s
            bw = max((f.width(t) for t in lines), default=0) + 32 * s
            bh = len(lines) * f.line_h + 24 * s
            x0, y0 = (W - bw) / 2, (H - bh) / 2
            ov.rect(x0, y0, bw, bh, (0.02, 0.02, 0.03, 0.88))
            ov.frame(x0, y0, bw, bh, ACCENT, s)
            for i, t in enumerate(lines):
                ov.label(t, x0 + 16 * s, y0 + bh - 12 * s - (i + 1) * f.line_h + f.descent, TEXT)

    def _doc(self, frame, s: float) -> None:
        """A docs page in a box over the views: title, then wrapped text from the scroll line."""
        ov, f = self.overlay, self.overlay.font
        title, text, first = frame.doc
        W, H = frame.size[0] * s, frame.size[1] * s
        view = next((v.rect for v in frame.views if v.name == frame.hud_view), None)
        left, width = (view.x * s, view.w * s) if view is not None else (0.0, W)  # stay inside the main view
        bw, bh = min(width - 48 * s, 760 * s), H * 0.78
        x0, y0 = left + 24 * s, (H - bh) / 2
        lines = doc_lines(text, lambda t: f.wrap(t, bw - 32 * s))
        fit = max(int((bh - 3 * f.line_h - 24 * s) // f.line_h), 1)
        first = min(first, max(len(lines) - fit, 0))
        shown = lines[first : first + fit]
        ov.rect(x0, y0, bw, bh, (0.03, 0.035, 0.05, 0.94))
        ov.frame(x0, y0, bw, bh, ACCENT, s)
        top = y0 + bh - 12 * s - f.line_h + f.descent
        ov.label(title, x0 + 16 * s, top, ACCENT)
        for i, t in enumerate(shown):
            ov.label(t, x0 + 16 * s, top - (i + 1.5) * f.line_h, TEXT)
        more = f"lines {first + 1}-{first + len(shown)} of {len(lines)}; PageUp/PageDown scroll, Help closes"
        ov.label(more, x0 + 16 * s, y0 + 10 * s, (0.6, 0.65, 0.75, 1.0))

    def _hud(self, hud, r: Rect, s: float) -> None:
        ov, f = self.overlay, self.overlay.font
        pad = 8 * s
        width = min(r.w - 2 * pad, 640 * s)
        lines = []
        if hud.step_title:
            lines.append((hud.step_title, ACCENT))
        if hud.step_instruction:
            lines += [(t, TEXT) for t in f.wrap(hud.step_instruction, width - 2 * pad)]
        for text, _left in hud.messages:
            lines += [(t, (1.0, 0.85, 0.3, 1.0)) for t in f.wrap(text, width - 2 * pad)]
        if not lines:
            return
        top = r.y + r.h - f.line_h - 14 * s  # under the viewport title
        bh = len(lines) * f.line_h + pad
        x0 = r.x + pad
        ov.rect(x0, top - bh, width, bh, (0.0, 0.0, 0.0, 0.55))
        for i, (t, c) in enumerate(lines):
            ov.label(t, x0 + pad, top - (i + 1) * f.line_h + f.descent, c, max_w=width - 2 * pad)

    def _panel(self, p: PanelDraw, hud, s: float) -> None:

        ov, f = self.overlay, self.overlay.font
        r = p.rect.scaled(s)
        ov.rect(r.x, r.y + r.h - TITLE_PX * s, r.w, TITLE_PX * s, (0.18, 0.20, 0.25, 1.0))
        ov.label(
            p.title or p.name,
            r.x + 8 * s,
            r.y + r.h - TITLE_PX * s + (TITLE_PX * s - f.ascent) / 2,
            TEXT,
            max_w=r.w - 16 * s,
        )
        lights = dict(hud.lights) if hud is not None else {}
        shown = set()
        for pl in p.placed:
            self._widget(pl, p, lights, s)
            shown.add(pl.spec["name"])
        y = below_widgets(p.placed, p.rect) * s
        hint = f.wrap(p.hint, r.w - 16 * s) if p.hint else []
        floor = r.y + (len(hint) * f.line_h + 8 * s if hint else 0)
        for name, state in [(n, v) for n, v in lights.items() if n not in shown]:
            y -= 22 * s
            if y < floor:
                break
            ov.disc(r.x + 18 * s, y + 8 * s, 7 * s, LIGHT_RGBA.get(state, LIGHT_RGBA["off"]))
            ov.label(name, r.x + 32 * s, y + 3 * s, TEXT, max_w=r.w - 40 * s)
        if hud is not None and hud.panel_text:
            y -= 6 * s
            for t in [t for line in hud.panel_text for t in f.wrap(line, r.w - 16 * s)]:
                y -= f.line_h
                if y < floor:
                    break
                ov.label(t, r.x + 8 * s, y + f.descent, TEXT)
        if hint:  # the help of the widget under the pointer, along the bottom
            ov.rect(r.x, r.y, r.w, floor - r.y, (0.08, 0.09, 0.11, 1.0))
            for i, t in enumerate(reversed(hint)):
                ov.label(t, r.x + 8 * s, r.y + 4 * s + i * f.line_h + f.descent, DIM)

    def _widget(self, pl, p: PanelDraw, lights: dict, s: float) -> None:
        ov = self.overlay
        spec = pl.spec
        name, kind = spec["name"], spec["kind"]
        r = pl.rect.scaled(s)
        f = ov.font_for(r.h / 2 if kind in ("slider", "dial") else r.h)  # short widgets get a smaller font
        value = p.values.get(name)
        off = name in p.disabled
        fg = DIM if off else TEXT
        label = spec.get("label") or name
        key = f" [{spec['key']}]" if spec.get("key") else ""
        mid = r.y + (r.h - f.ascent) / 2 + 1
        if kind == "button":
            ov.rect(r.x, r.y, r.w, r.h, (0.20, 0.22, 0.27, 1.0) if off else (0.25, 0.33, 0.45, 1.0))
            ov.frame(r.x, r.y, r.w, r.h, (0.4, 0.45, 0.55, 1.0), s)
            text = label + key
            ov.label(text, r.x + max((r.w - f.width(text)) / 2, 4 * s), mid, fg, max_w=r.w - 8 * s, font=f)
        elif kind == "toggle":
            bx = 16 * s
            ov.frame(r.x + 2 * s, r.y + (r.h - bx) / 2, bx, bx, fg, s)
            if value:
                ov.rect(r.x + 5 * s, r.y + (r.h - bx) / 2 + 3 * s, bx - 6 * s, bx - 6 * s, ACCENT if not off else DIM)
            ov.label(label + key, r.x + bx + 10 * s, mid, fg, max_w=r.w - bx - 12 * s, font=f)
        elif kind in ("slider", "dial"):
            v = float(value) if isinstance(value, (int, float)) else 0.0
            lo, hi = float(spec.get("min", 0.0)), float(spec.get("max", 1.0))
            t = (v - lo) / (hi - lo) if hi != lo else 0.0
            top = r.y + r.h - f.ascent - 2 * s
            ov.label(label + key, r.x + 2 * s, top, fg, max_w=r.w * 0.65, font=f)
            vt = f"{v:.3g}"
            ov.label(vt, r.x + r.w - f.width(vt) - 2 * s, top, ACCENT if not off else DIM, font=f)
            ty = r.y + 8 * s
            if kind == "slider":
                x0, x1 = r.x + 10 * s, r.x + r.w - 10 * s
                ov.rect(x0, ty - 2 * s, x1 - x0, 4 * s, (0.3, 0.32, 0.38, 1.0))
                ov.rect(x0, ty - 2 * s, (x1 - x0) * t, 4 * s, ACCENT if not off else DIM)
                ov.rect(x0 + (x1 - x0) * t - 4 * s, ty - 7 * s, 8 * s, 14 * s, fg)
            else:
                cx, rad = r.x + r.w / 2, 9 * s
                ov.label("-", r.x + 6 * s, ty - f.ascent / 2, fg, font=f)
                ov.label("+", r.x + r.w - 14 * s, ty - f.ascent / 2, fg, font=f)
                ov.disc(cx, ty + 2 * s, rad, (0.3, 0.32, 0.38, 1.0))
                ang = np.radians(225.0 - 270.0 * t)
                ov.segment(
                    cx,
                    ty + 2 * s,
                    cx + rad * np.cos(ang),
                    ty + 2 * s + rad * np.sin(ang),
                    ACCENT if not off else DIM,
                    2 * s,
                )
        elif kind == "light":
            state = lights.get(name, value if value in LIGHT_RGBA else "off")
            ov.disc(r.x + 10 * s, r.y + r.h / 2, 7 * s, LIGHT_RGBA.get(state, LIGHT_RGBA["off"]))
            ov.label(label, r.x + 24 * s, mid, fg, max_w=r.w - 26 * s, font=f)
        else:  # text
            shown = label if value in (None, False, "") else f"{label}: {value}" if label else str(value)
            ov.label(shown, r.x + 2 * s, mid, fg, max_w=r.w - 4 * s, font=f)

    def release(self) -> None:
        for gm in self.meshes.values():
            gm.release()
        self.meshes.clear()
        self.sphere.release()
        self.overlay.release()
        for o in (self.dyn_vao, self.dyn, self.mesh_prog, self.line_prog, self.id_prog):
            o.release()


def _trs(pos, radius: float) -> np.ndarray:
    m = np.eye(4) * float(radius)
    m[3, 3] = 1.0
    m[:3, 3] = np.asarray(pos, float)
    return m


def doc_lines(markdown: str, wrap) -> list[str]:
    """Markdown as plain wrapped lines: heading marks and emphasis dropped, lists and tables kept."""
    out = []
    for raw in markdown.splitlines():
        t = raw.rstrip()
        if t.startswith("#"):
            t = t.lstrip("#").strip().upper()
        t = t.replace("**", "").replace("`", "")
        if len(t) > 1 and t[0] == "*" and t[-1] == "*":
            t = t[1:-1]
        if t.startswith("|") or not t:
            out.append(t)
        else:
            out.extend(wrap(t) or [""])
    return out

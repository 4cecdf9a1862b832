"""Drawing the world: gathers meshes, materials, markers, lines, planes, panels and HUD into a `Frame`
and hands it to the GL renderer (thesis 3.3.4 linked views and controller; 5.3 Figs 5.6-5.8).

Stage: render (ORDER_RENDER). Installed only when rendering (window, snapshot, --screenshot-every).
Reads: Transform, MeshRef (+ the pack's [materials]: color, opacity, wireframe, shading), Deformable
(its soft body's positions, moved ids and alive links), Marker, PolyLine, Label, the pack's [planes],
ViewState, WidgetState, HudState, Settings, RunInfo. Writes: the soft bodies' moved ids (taken once the
moved vertices are queued for upload), the GPU buffers, PNG frames.

Where it draws: a `RenderTarget` resource inserted before the plugin is built (the window inserts its
own), else an EGL off-screen framebuffer the size of the window layout. In a window it draws every
frame; off screen it draws only when a frame is wanted - every `RunInfo.screenshot_every` frames, to
`OUT/frame_000123.png` (123 = App frame index) - or when `draw()` is called (snapshots, tests).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import esper
import moderngl
import numpy as np

from chainsim.components.core import Label, Marker, MeshRef, PolyLine, Transform, Wireframe
from chainsim.components.hud import HudState
from chainsim.components.resources import EntityIndex, InputState, PackResource, RunInfo, Settings
from chainsim.components.stages import ORDER_RENDER
from chainsim.game.render.context import egl_context, fbo_size, offscreen_framebuffer, release_framebuffer
from chainsim.game.render.png import read_rgba, write_png
from chainsim.game.render.radiograph import FluoroDraw, XrayMesh, image_size
from chainsim.game.render.renderer import Frame, MeshDraw, PanelDraw, Renderer, ViewDraw
from chainsim.systems.procedures import procedure_of
from chainsim.systems.tissue.deformable import Deformable
from chainsim.systems.view.cameras import ViewState, main_view, refresh_cameras
from chainsim.systems.view.picking import surface_cache
from chainsim.systems.view.ui import docbox, keyhelp
from chainsim.systems.view.ui.widgets import WidgetState

PLANE_COLORS = ((0.95, 0.35, 0.35, 0.22), (0.35, 0.9, 0.45, 0.22), (0.35, 0.55, 1.0, 0.22), (0.9, 0.8, 0.3, 0.22))
XRAY_OPACITY = 0.3
DISPLAY = "display"  # key prefix of GPU meshes drawn from a pack mesh's display copy
PLANE_PATCH_MM = 22.0  # half the side of a reference-plane patch


@dataclass(slots=True)
class RenderTarget:
    """Where frames go: a GL context and its framebuffer (window or off-screen)."""

    ctx: moderngl.Context
    fbo: moderngl.Framebuffer
    scale: float = 1.0  # framebuffer pixels per window pixel
    offscreen: bool = True
    size: tuple[int, int] | None = None  # framebuffer pixels, when fbo.size cannot be trusted (windows)
    samples: int = 1  # off screen: draw multisampled and resolve into `fbo` (smooth edges in PNGs)
    msaa: moderngl.Framebuffer | None = None
    hold: bool = False  # a window frame runs several fixed steps: draw only after the last one

    def multisampled(self) -> moderngl.Framebuffer:
        """The multisampled framebuffer matching `fbo` (off-screen targets with samples > 1)."""
        if self.msaa is not None and tuple(self.msaa.size) == tuple(self.fbo.size):
            return self.msaa

        if self.msaa is not None:
            release_framebuffer(self.ctx, self.msaa)
        size = fbo_size(self.fbo)
        self.msaa = self.ctx.framebuffer(
            color_attachments=[self.ctx.renderbuffer(size, 4, samples=self.samples)],
            depth_attachment=self.ctx.depth_renderbuffer(size, samples=self.samples),
        )
        return self.msaa

    def ensure_size(self, size: tuple[int, int]) -> None:
        """Off-screen targets follow the window layout size."""
        if not self.offscreen:
            return
        want = (max(int(round(size[0] * self.scale)), 1), max(int(round(size[1] * self.scale)), 1))
        if tuple(self.fbo.size) != want:
            release_framebuffer(self.ctx, self.fbo)
            self.fbo = offscreen_framebuffer(self.ctx, want)


def _deformable_type():
    return Deformable


def _material(pack, name: str) -> dict:
    mats = pack.section("materials")
    m = mats.get(name) if name else None
    if m is None:
        return {"color": (0.8, 0.8, 0.8, 1.0), "opacity": 1.0, "wireframe": False, "shading": "smooth"}
    return m


def sync_deformables(app) -> None:
    """Queue moved vertices for upload, taking each soft body's moved ids (every render-stage call, drawn
    or not)."""

    D = _deformable_type()
    if D is None:
        return
    renderer: Renderer = app.resource(Renderer)
    for ent, d in esper.get_component(D):
        dirty = d.body.take_dirty()
        gm = renderer.meshes.get(ent)
        if len(dirty) and gm is not None:
            gm.mark(dirty)


def _plane_quads(pack, half: float) -> list:
    out = []
    for i, (_name, pl) in enumerate(sorted(pack.section("planes").items())):
        n = np.asarray(pl["normal"], float)
        if np.linalg.norm(n) < 1e-12:
            continue
        n = n / np.linalg.norm(n)
        a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        u = np.cross(n, a)
        u /= np.linalg.norm(u)
        v = np.cross(n, u)
        p = np.asarray(pl["point"], float)
        corners = np.array(
            [p - half * u - half * v, p + half * u - half * v, p + half * u + half * v, p - half * u + half * v]
        )
        out.append((corners, PLANE_COLORS[i % len(PLANE_COLORS)]))
    return out


def page(app):
    """The open page as (title, markdown, footer buttons) or None: a docs page of the pack, the key
    overlay, or a notice (a question, a progress line) which takes the box over both."""

    hud = app.get_resource(HudState)
    if hud is None:
        return None
    pack = app.resource(PackResource).pack
    if hud.notice:
        return ("", hud.notice, None)
    if not hud.doc_open:
        return None
    if hud.doc_name == keyhelp.NAME:
        docs = pack.section("docs")
        text = keyhelp.keys_markdown(
            app.resource(PackResource).layout.get("widgets", []), hud.key_rows, [d["title"] for d in docs.values()]
        )
        return (keyhelp.TITLE, text, {"docs": bool(docs), "close": True})
    docs = pack.section("docs")
    if hud.doc_name not in docs:
        return None
    names = list(docs)
    k = names.index(hud.doc_name)
    buttons = {"prev": k > 0, "next": k + 1 < len(names), "close": True}
    return (docs[hud.doc_name]["title"], pack.doc_text(hud.doc_name), buttons)


def collect_frame(app):
    """Build the `Frame` for the current world (creates / updates GPU meshes as needed)."""

    target: RenderTarget = app.resource(RenderTarget)
    pack = app.resource(PackResource).pack
    vs: ViewState = app.resource(ViewState)
    refresh_cameras(app, vs)
    settings = app.resource(Settings)
    frame = Frame(
        size=tuple(app.resource(InputState).window_size),
        scale=target.scale,
        background=tuple(float(c) for c in settings.get("background", (0.08, 0.09, 0.11, 1.0))),
    )
    _collect_meshes(app, frame, pack, vs)
    for ent, (mk, tr) in esper.get_components(Marker, Transform):
        if mk.visible:
            frame.markers.append(
                (np.asarray(tr.position, float), float(mk.radius), tuple(float(c) for c in mk.color), ent)
            )
    for _ent, pl in esper.get_component(PolyLine):
        if pl.visible and len(pl.points) >= 2:
            frame.lines.append((np.asarray(pl.points, float).reshape(-1, 3), tuple(float(c) for c in pl.color)))
    for _ent, (lb, tr) in esper.get_components(Label, Transform):
        if lb.text:
            frame.labels.append((np.asarray(tr.position, float), lb.text, tuple(float(c) for c in lb.color)))
    if vs.layer_visible("planes") and pack.section("planes"):
        # small patches with an outline around each plane's point, not quads across the whole view
        frame.planes = _plane_quads(pack, PLANE_PATCH_MM)
        for corners, color in frame.planes:
            frame.lines.append((np.vstack([corners, corners[:1]]), (*color[:3], 0.9)))
    _collect_views(app, frame, vs)
    frame.hud = app.get_resource(HudState)
    frame.fluoro = fluoro_draw(app)
    main = main_view(vs)  # the step text, messages and pages: the same view the pointer's pages use
    frame.hud_view = main.name if main is not None and any(v.name == main.name for v in frame.views) else ""
    shown = page(app)
    if shown is not None and frame.hud_view:
        title, text, buttons = shown
        frame.doc = (title, text, 0 if frame.hud.notice else frame.hud.doc_scroll, buttons)
        frame.doc_box = docbox.box(vs.get(frame.hud_view).rect)
    return frame


def _collect_meshes(app, frame: Frame, pack, vs: ViewState) -> None:
    """Every visible mesh entity's draw (its GPU mesh uploaded where the body moved or was cut), each
    told the mesh that encloses it; GPU meshes of removed entities are let go."""
    renderer: Renderer = app.resource(Renderer)
    D = _deformable_type()
    cache = surface_cache(app)
    alive_ents = set()
    drawn_meshes: dict[str, list[MeshDraw]] = {}  # pack mesh name -> its entities' draws
    enclosed: list[tuple[MeshDraw, str]] = []  # draw, name of the mesh the pack says encloses it
    for ent, ref in esper.get_component(MeshRef):
        alive_ents.add(ent)
        if not ref.visible:
            continue
        d = esper.try_component(ent, D) if D is not None else None
        body = d.body if d is not None else None
        # a mesh that never deforms is drawn from its lighter display copy where the pack has one
        # (kept under its own key: the C-arm image draws the full mesh under the entity's)
        md = pack.mesh(ref.mesh) if d is not None else pack.display_mesh(ref.mesh)
        if len(md.triangles) == 0 and md.links is None:
            continue
        key = ent if md is pack.mesh(ref.mesh) else (DISPLAY, ent)
        alive_ents.add(key)
        gm = _gpu_mesh(renderer, cache, ent, key, md, body)
        draw = _mesh_draw(pack, vs, ent, ref, gm)
        if draw is None:
            continue
        frame.meshes.append(draw)
        drawn_meshes.setdefault(ref.mesh, []).append(draw)
        enclosed.append((draw, pack.manifest["meshes"][ref.mesh].get("inside", "")))
        gm.box()  # the box is taken after this frame's upload (it only grows after partial ones)
    for md, outer in enclosed:
        if outer and len(drawn_meshes.get(outer, ())) == 1:  # one enclosing entity, or none is meant
            md.inside = drawn_meshes[outer][0]
    for key in [k for k in renderer.meshes if k not in alive_ents]:
        renderer.forget(key)  # entity removed


def _gpu_mesh(renderer: Renderer, cache, ent: int, key, md, body):
    """The entity's GPU mesh, with the soft body's current positions and, after a cut, its live links and
    triangles (`body` None: a mesh that does not deform)."""
    local = np.asarray(body.positions) if body is not None and body.n == len(md.vertices) else md.vertices
    graph = body.graph if body is not None else None
    links = np.asarray(graph.links) if graph is not None else None
    gm = renderer.mesh(key, local, md.triangles, links if links is not None else md.links)
    if body is not None:
        gm.upload(local)
        alive = body.alive
        if len(alive) and links is not None:  # links: the graph's
            dead = int(len(alive) - np.count_nonzero(alive))
            if dead != getattr(gm, "dead_links", 0):
                gm.dead_links = dead
                gm.set_links(links[alive])
                gm.set_triangles(cache.live_triangles(ent, md.triangles, body))
    return gm


def _mesh_draw(pack, vs: ViewState, ent: int, ref: MeshRef, gm) -> MeshDraw | None:
    """How the entity's mesh is drawn (colour, see-through layers, wireframe, shading); None when it is
    wholly transparent."""
    mat = _material(pack, ref.material)
    color = [float(c) for c in mat["color"]]
    color[3] *= float(mat.get("opacity", 1.0))
    if ref.layer and ref.layer in vs.xray:
        color[3] = min(color[3], XRAY_OPACITY)
    if color[3] <= 0.0:
        return None
    wire = (
        bool(mat.get("wireframe", False))
        or (bool(ref.layer) and ref.layer in vs.wire)
        or esper.has_component(ent, Wireframe)
    )
    tr = esper.try_component(ent, Transform)
    model = tr.matrix() if tr is not None else np.eye(4)
    return MeshDraw(gm, model, tuple(color), wire, mat.get("shading", "smooth"), ent)


def _collect_views(app, frame: Frame, vs: ViewState) -> None:
    """The shown viewports, and the widgets placed on each panel with the hovered one's help."""
    st: WidgetState = app.resource(WidgetState)
    index = app.get_resource(EntityIndex)
    for vp in vs.viewports:
        if not vp.visible:
            continue
        hide = -1
        if vp.kind == "attached" and index is not None:  # the camera's own entity would fill the view
            hide = index.get(vp.spec.get("attach", ""), -1)
        frame.views.append(ViewDraw(vp.name, vp.kind, vp.rect, vp.camera, vp.spec.get("title", ""), hide_entity=hide))
        if vp.kind == "panel":
            placed = vs.panels.get(vp.name, [])
            hint = next((p.spec.get("help", "") for p in placed if p.spec["name"] == vs.hover), "")
            frame.panels.append(
                PanelDraw(vp.name, vp.rect, vp.spec.get("title", ""), placed, st.values, st.disabled, hint)
            )


def fluoro_draw(app) -> FluoroDraw | None:
    """The X-ray view's image request: the pack's procedure's X-ray image (for the needle procedure, the
    C-arm's pose at its last image) and every mesh whose material attenuates X-rays (visible on screen or
    not: hiding the skin does not take it out of the beam). None when the layout has no "fluoro"
    viewport or the procedure takes no image now."""
    vs: ViewState = app.resource(ViewState)
    if not any(vp.kind == "fluoro" for vp in vs.viewports):
        return None
    pack = app.resource(PackResource).pack
    proc = procedure_of(pack.manifest)
    shot = proc.xray(app) if proc is not None and proc.xray is not None else None
    if shot is None:
        return None
    renderer: Renderer = app.resource(Renderer)
    meshes = []
    for ent, ref in esper.get_component(MeshRef):
        mu = float(_material(pack, ref.material).get("attenuation", 0.0))
        if mu <= 0.0:
            continue
        md = pack.mesh(ref.mesh)
        if len(md.triangles) == 0:
            continue
        d = esper.try_component(ent, Deformable)
        local = np.asarray(d.body.positions) if d is not None and d.body.n == len(md.vertices) else md.vertices
        tr = esper.try_component(ent, Transform)
        meshes.append(XrayMesh(renderer.mesh(ent, local, md.triangles, md.links), tr.matrix() if tr else np.eye(4), mu))
    side = max((min(vp.rect.w, vp.rect.h) for vp in vs.viewports if vp.kind == "fluoro"), default=0)
    target = app.get_resource(RenderTarget)
    side *= target.scale if target is not None else 1.0
    size = image_size(side)
    return FluoroDraw(
        shot.camera,
        shot.image_id,
        meshes,
        shot.status,
        shot.live,
        shot.attempt,
        shot.images,
        vs.xray_window,
        vs.xray_level,
        size,
    )


def capture_fluoro(app) -> None:
    """Make the C-arm image now if the arm took one since the last: the view then shows the world as it
    was at the shot, frozen, however long until the next frame is drawn."""
    with app.active():
        request = fluoro_draw(app)
        if request is not None:
            app.resource(Renderer).fluoro.update(request)


def draw(app):
    """Draw the current world into the render target now; returns the Frame drawn."""

    target: RenderTarget = app.resource(RenderTarget)
    target.ensure_size(app.resource(InputState).window_size)
    with app.active():
        sync_deformables(app)
        frame = collect_frame(app)
        if target.offscreen and target.samples > 1:
            ms = target.multisampled()
            app.resource(Renderer).render(frame, ms)
            target.ctx.copy_framebuffer(target.fbo, ms)  # resolves the samples
        else:
            app.resource(Renderer).render(frame, target.fbo, target.size)
        hud = app.get_resource(HudState)
        if frame.doc_shown is not None and hud is not None and not hud.notice:
            hud.doc_scroll = frame.doc_shown[0]  # scrolled past the end: back to the last screenful
    return frame


def read_pixels(app) -> np.ndarray:
    """The render target's pixels, (H, W, 4) uint8, top row first."""

    target: RenderTarget = app.resource(RenderTarget)
    if target.size is not None:
        return read_rgba(target.fbo, (0, 0, *target.size))
    return read_rgba(target.fbo)


def screenshot(app, path) -> Path:
    """Draw now and write a PNG. A window's own framebuffer may be multisampled (not readable), so
    window screenshots are drawn again into an off-screen framebuffer of the same size."""

    target: RenderTarget = app.resource(RenderTarget)
    if target.offscreen:
        draw(app)
        return write_png(path, read_pixels(app))
    size = target.size or fbo_size(target.fbo)
    fbo = offscreen_framebuffer(target.ctx, size)
    window_fbo = target.fbo
    try:
        target.fbo = fbo
        draw(app)
        rgba = read_rgba(fbo, (0, 0, *size))
    finally:
        target.fbo = window_fbo
        window_fbo.use()
        release_framebuffer(target.ctx, fbo)
    return write_png(path, rgba)


class RenderSystem:
    def __call__(self, app) -> None:

        target: RenderTarget = app.resource(RenderTarget)
        capture_fluoro(app)
        if not target.offscreen:
            if target.hold:
                sync_deformables(app)
            else:
                draw(app)
            return
        sync_deformables(app)
        info = app.get_resource(RunInfo)
        k = info.screenshot_every if info is not None else 0
        if k and info.out_dir and app.time.frame % k == 0:
            screenshot(app, Path(info.out_dir) / f"frame_{app.time.frame:06d}.png")


def plugin(app) -> None:

    target = app.get_resource(RenderTarget)
    if target is None:
        ctx = egl_context()
        samples = 4 if ctx.max_samples >= 4 else 1
        target = app.insert_resource(
            RenderTarget(ctx, offscreen_framebuffer(ctx, app.resource(InputState).window_size), samples=samples)
        )
    renderer = app.insert_resource(Renderer(target.ctx))

    def release():
        renderer.release()
        if target.offscreen:
            if target.msaa is not None:
                release_framebuffer(target.ctx, target.msaa)
            release_framebuffer(target.ctx, target.fbo)

    app.on_close(release)
    app.add_system("render", RenderSystem(), order=ORDER_RENDER, name="render")

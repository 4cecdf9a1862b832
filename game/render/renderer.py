"""The frame renderer: every viewport of a layout, the control panel and the HUD, in one framebuffer.

Per 3-D viewport (thesis 3.3.4: global view, needle-tip view; 5.3 Figs 5.6-5.8: wireframe and shaded
deformation): clear its rectangle, then draw opaque meshes, wireframes (the ChainMail links), markers
and poly-lines with depth testing; then transparent meshes and planes sorted back to front with depth
writes off, each drawn back faces first and front faces second, so a see-through skin over a skull
blends in the right order. Panels and the HUD are drawn last in window pixels (`Overlay`).

The renderer only sees plain data (`Frame`); `chainsim.game.render.render_system` gathers it from the world.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import moderngl
import numpy as np

from chainsim.game.render import culling, panelview, shaders
from chainsim.game.render.context import release_framebuffer
from chainsim.game.render.docview import PageView
from chainsim.game.render.icosphere import icosphere
from chainsim.game.render.meshbuf import ORDER_DIRECTIONS, GpuMesh
from chainsim.game.render.overlay import Overlay
from chainsim.game.render.radiograph import FluoroDraw, FluoroRenderer
from chainsim.game.render.viewcache import ViewCache, base_key, item_keys
from chainsim.systems.view.ui.viewports import Camera, Rect

SHADING = {"smooth": 0, "flat": 1, "unlit": 2}
#: a cached view is drawn into its image after this many frames without change (chainsim.game.render.viewcache)
STILL_FRAMES = 1
#: an item that changed within this many frames is live: drawn over its view's layer rather than in it,
#: so a dial turned in fits and starts does not redraw the layer at each pause (chainsim.game.render.viewcache)
LIVE_FRAMES = 12

RGBA = tuple[float, float, float, float]  # a colour, each part in [0, 1]
PANEL_BG, TEXT, DIM, ACCENT, LIGHT_RGBA = (
    panelview.PANEL_BG,
    panelview.TEXT,
    panelview.DIM,
    panelview.ACCENT,
    panelview.LIGHT_RGBA,
)


@dataclass(slots=True)
class MeshDraw:
    gpu: GpuMesh
    model: np.ndarray  # 4 x 4
    color: tuple  # RGBA, alpha = opacity
    wireframe: bool = False
    shading: str = "smooth"
    entity: int = -1
    inside: MeshDraw | None = None  # a closed mesh wholly enclosing this one (not drawn while it hides it)


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
    placed: list  # chainsim.systems.view.ui.widgets.Placed
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
    # an open page: (title, markdown text, first line, footer buttons name -> enabled) in `doc_box`
    doc: tuple[str, str, int, dict | None] | None = None
    doc_box: Rect | None = None
    doc_shown: tuple[int, int] | None = None  # after drawing: (first line shown, last first line)
    fluoro: FluoroDraw | None = None  # the C-arm view's image request (chainsim.game.render.radiograph)


def _mat(m: np.ndarray) -> bytes:
    return np.asarray(m, np.float32).T.tobytes()  # GLSL reads column-major


def _set(prog, name: str, value) -> None:
    """Set a uniform if the compiler kept it (unused ones are optimised away). The program keeps its
    uniforms by name (None: dropped), as `name in prog` walks every member of the program and a frame
    sets a few hundred uniforms."""
    found: dict[str, Any] | None = prog.__dict__.get("_chainsim_uniforms")
    if found is None:
        found = prog.__dict__["_chainsim_uniforms"] = {}
    u = found.get(name, False)
    if u is False:
        u = found[name] = prog[name] if name in prog else None
    if u is None:
        return
    if isinstance(value, bytes):
        u.write(value)
    else:
        u.value = value


@contextmanager
def _writes_off(fbo):
    """Neither colour nor depth is written inside (occlusion queries). moderngl hands a framebuffer's
    masks to GL when it is bound, so it is bound again after each change."""
    fbo.color_mask = (False, False, False, False)
    fbo.depth_mask = False
    fbo.use()
    try:
        yield
    finally:
        fbo.color_mask = (True, True, True, True)
        fbo.depth_mask = True
        fbo.use()


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
        self.pages = PageView(self.overlay)
        # viewport rect -> label in sight (this frame): a list of bools, or of queries not yet read
        self._labels_seen: dict[tuple, list] = {}
        self._fluoro: FluoroRenderer | None = None  # made on first use (only layouts with a C-arm view)
        self.defer_shots = False  # the window's: an X-ray's cue is drawn before its image is made
        self.cull_enclosed = True  # off: meshes inside an opaque one are drawn anyway (tests compare)
        self.cull_back = True  # off: back faces of closed opaque meshes are drawn too (tests compare)
        self._label_q: list[list] = []  # occlusion queries of the labels, a set per scene drawn in a frame
        self._label_sets = 0  # sets used in this frame
        self.view_cache: ViewCache | None = None  # `cache_views()` turns it on
        self.cull_outside = True  # off: big meshes are handed to GL whole in every draw (tests compare)
        self.defer_labels = True  # off: label queries are read where the labels are laid out (tests compare)
        self._culled: dict[int, _Culled] = {}  # GpuMesh.serial -> its list of triangles in sight
        self._model_mats: dict[bytes, tuple[bytes, bytes]] = {}  # model matrix -> its uniforms (model, normals)

    @property
    def fluoro(self) -> FluoroRenderer:
        """The C-arm image maker (chainsim.game.render.radiograph), created on first use."""
        if self._fluoro is None:
            self._fluoro = FluoroRenderer(self.ctx)
            self._fluoro.defer_shots = self.defer_shots
        return self._fluoro

    # -- meshes ------------------------------------------------------------------------------
    def mesh(self, key, vertices: np.ndarray, triangles: np.ndarray, links: np.ndarray | None = None) -> GpuMesh:
        """The GPU mesh for `key`, created from the arrays on first use."""
        gm = self.meshes.get(key)
        if gm is None or gm.n != len(vertices):
            if gm is not None:
                self._release_mesh(gm)
            gm = self.meshes[key] = GpuMesh(self.ctx, vertices, triangles, links)
        return gm

    def forget(self, key) -> None:
        gm = self.meshes.pop(key, None)
        if gm is not None:
            self._release_mesh(gm)

    def _release_mesh(self, gm: GpuMesh) -> None:
        c = self._culled.pop(gm.serial, None)
        if c is not None:
            c.release()
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
        self._labels_seen.clear()
        self._label_sets = 0
        if frame.fluoro is not None:
            self.fluoro.update(frame.fluoro)  # a new C-arm image, when one was taken
            fbo.use()
        covered = sum(v.rect.scaled(s).w * v.rect.scaled(s).h for v in frame.views)
        if covered < W * H:  # viewports clear their own rectangles; clear the rest only when some shows
            fbo.clear(*frame.background, depth=1.0)
        # Views copied from their images go first and the drawing after: under a software renderer a
        # copy into the frame waits until everything already queued for the frame is rasterised,
        # so a copy after a drawn view would leave the rasteriser idle while this thread goes on.
        later = []
        items = None  # viewcache.item_keys(frame), made once for all the cached views
        for view in frame.views:
            r = view.rect.scaled(s)
            if r.w <= 0 or r.h <= 0:
                continue
            clear = view.clear or (
                PANEL_BG
                if view.kind == "panel"
                else (0.0, 0.0, 0.0, 1.0)
                if view.kind == "fluoro"
                else frame.background
            )
            ctx.scissor = (r.x, r.y, r.w, r.h)
            ctx.viewport = (r.x, r.y, r.w, r.h)
            is_3d = view.camera is not None and view.kind not in ("panel", "fluoro")
            if is_3d and self.view_cache is not None:
                items = item_keys(frame) if items is None else items
                draw = self._cached_scene(frame, view, r, fbo, clear, items)
                if draw is not None:
                    later.append((r, draw))
                continue
            later.append((r, partial(self._plain_view, frame, view, r, fbo, clear, is_3d)))
        for r, draw in later:
            ctx.scissor = (r.x, r.y, r.w, r.h)
            ctx.viewport = (r.x, r.y, r.w, r.h)
            draw()
        if self.view_cache is not None:
            self.view_cache.forget({v.name for v in frame.views})
        ctx.scissor = None
        ctx.viewport = (0, 0, W, H)
        self.overlay.set_scale(s)
        self._overlay(frame)
        self.overlay.flush((W, H))
        ctx.disable(ctx.BLEND)

    def _plain_view(self, frame: Frame, view: ViewDraw, r: Rect, fbo, clear: RGBA, is_3d: bool) -> None:
        fbo.clear(*clear, depth=1.0, viewport=(r.x, r.y, r.w, r.h))
        if view.kind == "fluoro":
            if frame.fluoro is not None:
                self.fluoro.draw(r)
        elif is_3d and view.camera is not None:  # is_3d says it has one
            self._scene(frame, view.camera, r, fbo, view.hide_entity)

    def cache_views(self, on: bool = True) -> None:
        """Keep each 3-D view's image and draw it again only when what it shows changed
        (chainsim.game.render.viewcache); for windows, where most frames repeat most views."""
        if on and self.view_cache is None:
            self.view_cache = ViewCache(self.ctx)
        elif not on and self.view_cache is not None:
            self.view_cache.release()
            self.view_cache = None

    def _cached_scene(self, frame: Frame, view: ViewDraw, r: Rect, fbo, clear: RGBA, items: list):
        """A view whose key is that of its image is copied from it. A view in which only some items
        move (the needle while a dial turns) over an unchanged camera is its layer - the image of the
        other items, with their depth - copied, and the moving items drawn over it (`_layered`).
        Otherwise a view that changed within the last STILL_FRAMES frames is drawn straight into
        `fbo` (while it keeps changing, as in an orbit, an image would only add a copy); once it has
        kept still that long it is drawn into its image and copied from then on.

        Copies are made now; what is drawn into the frame is returned as a function for `render` to
        call after every view's copies (None: nothing to draw)."""
        ctx = self.ctx
        vc, cam = self.view_cache, view.camera
        assert vc is not None and cam is not None  # render() caches 3-D views only, with the cache on
        cv = vc.slot(view.name, (r.w, r.h))
        base = base_key(frame, view, r, clear)
        if len(items) == len(cv.items):
            cv.age = [a + 1 if k == o else 0 for a, k, o in zip(cv.age, items, cv.items, strict=True)]
        else:  # a new view, or items came or went: none is known to keep still
            cv.age = [0 if cv.last is not None else LIVE_FRAMES] * len(items)
        cv.items = items
        key = (base, tuple(items))
        base_still = cv.last is not None and cv.last[0] == base
        cv.still = cv.still + 1 if key == cv.last else 0
        cv.last = key
        layered = False
        if key == cv.key:
            vc.reused += 1
        elif base_still and (layered := self._layered(frame, view, r, fbo, clear, cv, base, items)) is not False:
            return layered
        elif cv.still < STILL_FRAMES:
            vc.direct += 1

            def draw():
                fbo.clear(*clear, depth=1.0, viewport=(r.x, r.y, r.w, r.h))
                self._scene(frame, cam, r, fbo, view.hide_entity)

            return draw
        else:
            local = Rect(0, 0, r.w, r.h)
            cv.fbo.use()
            ctx.scissor = None
            ctx.viewport = (0, 0, r.w, r.h)
            cv.fbo.clear(*clear, depth=1.0)
            self._scene(frame, cam, local, cv.fbo, view.hide_entity)
            cv.seen = self._seen(self._labels_seen.pop((0, 0, r.w, r.h), []))
            cv.key = key
            vc.redrawn += 1
            fbo.use()
            ctx.scissor = (r.x, r.y, r.w, r.h)
            ctx.viewport = (r.x, r.y, r.w, r.h)
        self._labels_seen[(r.x, r.y, r.w, r.h)] = cv.seen
        vc.copy(cv, r)
        return None

    def _layered(self, frame: Frame, view: ViewDraw, r: Rect, fbo, clear: RGBA, cv, base, items):
        """Draw the view as its layer plus its live items (changed within the last LIVE_FRAMES frames),
        when that is exact and cheaper: the live items are opaque, no still mesh's hiding depends on a
        live one, and the still items hold at least as many triangles. The layer holds the still
        opaque items with their depth; with still see-through items (a see-through skin) a second
        image holds them blended over it, and each frame only the live items' screen box is made
        again from the opaque layer, the live items and the see-through items. Returns the drawing of
        the live items (after the copies, made now; None if nothing of them shows), or False: not
        used."""
        live = [i for i, a in enumerate(cv.age) if a < LIVE_FRAMES]
        if not live or len(live) == len(items):
            return False
        nm, nk, nl = len(frame.meshes), len(frame.markers), len(frame.lines)
        live_set = set(live)
        tri_live = tri_still = 0
        for i, m in enumerate(frame.meshes):
            if i in live_set:
                if m.color[3] < 0.999:
                    return False
                tri_live += m.gpu.n_indices
            else:
                if m.inside is not None and any(m.inside is frame.meshes[j] for j in live if j < nm):
                    return False
                tri_still += m.gpu.n_indices
        for i in live:
            if nm <= i < nm + nk and frame.markers[i - nm][2][3] < 0.999:
                return False
            if i >= nm + nk + nl:  # a plane: always see-through
                return False
        if tri_still < tri_live:
            return False
        ctx = self.ctx
        vc = self.view_cache
        cam, hide = view.camera, view.hide_entity
        assert vc is not None and cam is not None  # called by _cached_scene
        still_set = frozenset(range(len(items))) - live_set
        see_through = (
            any(m.color[3] < 0.999 for i, m in enumerate(frame.meshes) if i not in live_set)
            or any(frame.markers[k][2][3] < 0.999 for k in range(nk) if nm + k not in live_set)
            or any(nm + nk + nl + k not in live_set for k in range(len(frame.planes)))
        )
        layer_key = ("layer", base, tuple(live), tuple(items[i] for i in sorted(still_set)))
        if cv.key != layer_key:
            local = Rect(0, 0, r.w, r.h)
            cv.fbo.use()
            ctx.scissor = None
            ctx.viewport = (0, 0, r.w, r.h)
            cv.fbo.clear(*clear, depth=1.0)
            self._scene(frame, cam, local, cv.fbo, hide, skip=live_set, part="opaque" if see_through else "all")
            cv.seen = self._seen(self._labels_seen.pop((0, 0, r.w, r.h), []))
            if see_through:
                over_fbo, _ = vc.over(cv)
                over_fbo.use()
                vc.copy(cv, local, depth=True)
                self._scene(frame, cam, local, over_fbo, hide, skip=live_set, part="see-through")
            cv.key = layer_key
            cv.layers += 1
            fbo.use()
            ctx.scissor = (r.x, r.y, r.w, r.h)
            ctx.viewport = (r.x, r.y, r.w, r.h)
        vc.layered += 1
        self._labels_seen[(r.x, r.y, r.w, r.h)] = cv.seen
        if see_through:
            vc.copy(cv, r, image=vc.over(cv)[1])
            box = self._screen_box(frame, cam, r, live, hide)
            if box is None:
                return None
            vc.copy(cv, r, depth=True, box=box)

            def draw():
                ctx.scissor = box
                self._scene(frame, cam, r, fbo, hide, skip=still_set, part="opaque", queries=False)
                self._scene(frame, cam, r, fbo, hide, skip=live_set, part="see-through")
                ctx.scissor = (r.x, r.y, r.w, r.h)

            return draw
        vc.copy(cv, r, depth=True)
        return partial(self._scene, frame, cam, r, fbo, hide, skip=still_set, queries=False)

    def _screen_box(self, frame: Frame, cam: Camera, r: Rect, which: list[int], hide: int):
        """Scissor box (x, y, w, h) in framebuffer pixels holding the items numbered `which` as drawn in
        view rectangle `r`, with a margin; all of `r` when one reaches behind the eye; None when none
        of them shows."""
        nm, nk = len(frame.meshes), len(frame.markers)
        pts = []
        for i in which:
            if i < nm:
                m = frame.meshes[i]
                if hide >= 0 and m.entity == hide:
                    continue
                lo, hi = m.gpu.box()
                corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
                model = np.asarray(m.model, float)
                pts.append(corners @ model[:3, :3].T + model[:3, 3])
            elif i < nm + nk:
                pos, radius, _c, ent = frame.markers[i - nm]
                if hide >= 0 and ent == hide:
                    continue
                pos = np.asarray(pos, float)
                pts.append(
                    np.array(
                        [
                            pos + [sx * radius, sy * radius, sz * radius]
                            for sx in (-1, 1)
                            for sy in (-1, 1)
                            for sz in (-1, 1)
                        ]
                    )
                )
            else:
                pts.append(np.asarray(frame.lines[i - nm - nk][0], float).reshape(-1, 3))
        if not pts:
            return None
        p = np.vstack(pts)
        clip = np.c_[p, np.ones(len(p))] @ np.asarray(cam.view_projection(r.aspect), float).T
        full = (r.x, r.y, r.w, r.h)
        if (clip[:, 3] <= 1e-9).any():
            return full
        ndc = clip[:, :2] / clip[:, 3:4]
        x0 = int(np.floor(r.x + (ndc[:, 0].min() * 0.5 + 0.5) * r.w)) - 2
        x1 = int(np.ceil(r.x + (ndc[:, 0].max() * 0.5 + 0.5) * r.w)) + 2
        y0 = int(np.floor(r.y + (ndc[:, 1].min() * 0.5 + 0.5) * r.h)) - 2
        y1 = int(np.ceil(r.y + (ndc[:, 1].max() * 0.5 + 0.5) * r.h)) + 2
        x0, y0 = max(x0, r.x), max(y0, r.y)
        x1, y1 = min(x1, r.x + r.w), min(y1, r.y + r.h)
        if x1 <= x0 or y1 <= y0:
            return None
        return (x0, y0, x1 - x0, y1 - y0)

    def _mesh_uniforms(self, prog, vp: np.ndarray, m: MeshDraw, eye) -> None:
        model = np.asarray(m.model, float)
        _set(prog, "u_mvp", _mat(vp @ model))
        key = model.tobytes()
        mats = self._model_mats.get(key)
        if mats is None:  # the same few model matrices come back draw after draw
            lin = model[:3, :3]
            det = np.linalg.det(lin)
            nm = np.linalg.inv(lin).T if abs(det) > 1e-30 else np.eye(3)
            if len(self._model_mats) > 256:
                self._model_mats.clear()
            mats = self._model_mats[key] = (_mat(model), _mat(nm))
        _set(prog, "u_model", mats[0])
        _set(prog, "u_normal_mat", mats[1])
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
            if not m.gpu.n_indices:
                return
            first = None
            if m.color[3] >= 0.999 and m.gpu.orderable:  # nearest triangles first: hidden ones fail the depth test
                model = np.asarray(m.model, float)
                first = m.gpu.nearest_first(np.linalg.solve(model, np.r_[np.asarray(eye, float), 1.0])[:3])
            if self.cull_outside and self._draw_visible(m, vp, first):
                return
            if first is None:
                m.gpu.vao(self.mesh_prog, "tri").render(self.ctx.TRIANGLES, vertices=m.gpu.n_indices)
            else:
                m.gpu.vao(self.mesh_prog, "ordered").render(self.ctx.TRIANGLES, vertices=m.gpu.n_indices, first=first)

    def _draw_visible(self, m: MeshDraw, vp, first: int | None) -> bool:
        """Draw only the triangles of a big mesh, as loaded, that can touch the viewport's scissor box,
        in the order the whole mesh would be drawn in (`first`: its nearest-first order; None: its
        stored order), so the image is the same (chainsim.game.render.culling). False when nothing would be
        left out, or not enough to pay: then the caller draws the whole mesh."""
        gm = m.gpu
        if gm.version or gm.n_indices != gm.tris.size or len(gm.tris) < culling.CULL_MIN:
            return False
        ctx = self.ctx
        mvp = np.asarray(vp, float) @ np.asarray(m.model, float)
        planes = culling.region_planes(mvp, ctx.viewport, ctx.scissor)
        if planes is None:
            return True  # an empty box: nothing to draw
        c = self._culled.get(gm.serial)
        if c is None:
            c = self._culled[gm.serial] = _Culled(gm)
        if culling.box_inside(planes, c.corners):
            return False
        order = -1 if first is None else first // gm.n_indices
        key = (planes.tobytes(), order)
        if c.key != key:  # the two faces of a see-through mesh share one list
            keep = culling.visible_triangles(gm.pos, gm.tris, planes)
            if order >= 0:  # in the stored nearest-first order, kept triangles keep their places
                sorted_ids = c.order(order)
                ids = sorted_ids[keep[sorted_ids]]
            else:
                ids = np.flatnonzero(keep)
            c.n = len(ids)
            if c.n > (1.0 - culling.CULL_SHARE) * len(gm.tris):
                c.key, c.n = key, -1
                return False
            data = c.tris32[ids].tobytes()
            if len(data) > c.buffer.size:
                c.buffer.orphan(max(len(data), 2 * c.buffer.size))
            elif data:
                c.buffer.orphan()  # fresh storage: a draw still queued keeps the old list
            if data:
                c.buffer.write(data)
            c.key = key
        if c.n < 0:
            return False
        if c.n:
            c.vao(self.mesh_prog).render(ctx.TRIANGLES, vertices=3 * c.n)
        return True

    def _dyn_draw(self, pts: np.ndarray, mode, vp, color) -> None:
        data = np.ascontiguousarray(pts, np.float32).tobytes()
        if len(data) > self.dyn.size:
            self.dyn.orphan(len(data) * 2)
        self.dyn.write(data)
        _set(self.line_prog, "u_mvp", _mat(vp))
        _set(self.line_prog, "u_color", tuple(float(c) for c in color))
        self.dyn_vao.render(mode, vertices=len(pts))

    def _near_clear_of(self, m: MeshDraw, cam: Camera, aspect: float) -> bool:
        """Whether the eye is outside the mesh's box by more than the reach of the near plane's
        corners: then the eye is outside the mesh and the near plane cuts nothing of it."""
        lo, hi = m.gpu.box()
        model = np.asarray(m.model, float)
        centre = model[:3, :3] @ (0.5 * (lo + hi)) + model[:3, 3]
        half = np.abs(model[:3, :3]) @ (0.5 * (hi - lo))
        eye = np.asarray(cam.eye, float)
        gap = np.linalg.norm(np.maximum(np.abs(eye - centre) - half, 0.0))
        t = np.tan(np.radians(cam.fov) / 2.0)
        return bool(gap > cam.near * np.sqrt(1.0 + t * t * (1.0 + aspect * aspect)) * 1.01)

    def _enclosed_and_hidden(self, m: MeshDraw, cam: Camera, aspect: float, hide: int) -> bool:
        """Whether `m` lies inside a closed mesh drawn opaque in this view, seen from outside: then no
        fragment of it can show (the pack states the enclosure and a test checks it on the meshes)."""
        outer = m.inside
        return (
            self.cull_enclosed
            and outer is not None
            and outer.color[3] >= 0.999
            and not outer.wireframe
            and not (hide >= 0 and outer.entity == hide)
            and np.array_equal(np.asarray(outer.model, float), np.asarray(m.model, float))
            and self._near_clear_of(outer, cam, aspect)
        )

    def _label_queries(self, frame: Frame, vp, eye, r: Rect) -> None:
        """Which labels the opaque scene leaves in sight: a small sphere at each label's point is drawn
        without colour or depth writes inside an occlusion query (before markers, which would hide it),
        so a label behind the skull is not drawn over it. The queries are read when the labels are
        laid out (`_seen`), after every view is queued: reading one waits for the rasteriser."""
        ctx = self.ctx
        if not frame.labels:
            self._labels_seen[(r.x, r.y, r.w, r.h)] = []
            return
        if self._label_sets == len(self._label_q):
            self._label_q.append([])
        queries = self._label_q[self._label_sets]  # kept: reused every frame
        self._label_sets += 1
        while len(queries) < len(frame.labels):
            queries.append(ctx.query(samples=True))
        with _writes_off(ctx.fbo):
            for q, (pos, _text, _color) in zip(queries, frame.labels):
                with q:
                    self._draw_mesh(MeshDraw(self.sphere, _trs(pos, 1.2), (1, 1, 1, 1)), vp, eye)
        self._labels_seen[(r.x, r.y, r.w, r.h)] = queries[: len(frame.labels)]

    @staticmethod
    def _seen(found: list) -> list[bool]:
        """Label visibility from `_labels_seen`: its bools, or its queries read."""
        return [q if isinstance(q, bool) else q.samples > 0 for q in found]

    def _scene(
        self,
        frame: Frame,
        cam: Camera,
        r: Rect,
        fbo,
        hide: int = -1,
        skip=frozenset(),
        part: str = "all",
        queries: bool = True,
    ) -> None:
        """Draw the view's items: all of them (`part` "all"), the opaque ones ("opaque") or the see-through
        ones over what is there ("see-through"); items numbered in `skip` (viewcache.item_keys order)
        are left out. Label visibility is found in the opaque part, before the markers (unless not
        `queries`)."""
        ctx = self.ctx
        vp = cam.view_projection(r.aspect)
        eye = np.asarray(cam.eye, float)
        ctx.enable(ctx.DEPTH_TEST)
        ctx.disable(ctx.BLEND | ctx.CULL_FACE)
        fbo.depth_mask = True
        opaque = part != "see-through"
        see_through: list[tuple[str, Any]] = []  # ("mesh", MeshDraw) or ("plane", (corners, colour))
        nm, nk, nl = len(frame.meshes), len(frame.markers), len(frame.lines)
        for i, m in enumerate(frame.meshes):
            if i in skip or (hide >= 0 and m.entity == hide):
                continue
            if self._enclosed_and_hidden(m, cam, r.aspect, hide):
                continue
            if m.color[3] < 0.999:
                see_through.append(("mesh", m))
            elif not opaque:
                continue
            elif (
                self.cull_back and not m.wireframe and m.gpu.closed_outward() and self._near_clear_of(m, cam, r.aspect)
            ):
                # seen from outside a closed surface, its back faces are all behind its front faces:
                # skipping them before rasterising halves the work of the skin under a software renderer
                ctx.enable(ctx.CULL_FACE)
                ctx.cull_face = "back"
                self._draw_mesh(m, vp, eye)
                ctx.disable(ctx.CULL_FACE)
            else:
                self._draw_mesh(m, vp, eye)
        if opaque and queries:
            self._label_queries(frame, vp, eye, r)
        for k, (pos, radius, color, ent) in enumerate(frame.markers):
            if nm + k in skip or (hide >= 0 and ent == hide):
                continue
            if np.linalg.norm(np.asarray(eye, float) - np.asarray(pos, float)) <= radius * 1.05:
                continue  # a camera inside a marker (the tip view on its entry mark) would see only the marker
            md = MeshDraw(self.sphere, _trs(pos, radius), color, entity=ent)
            if color[3] < 0.999:
                see_through.append(("mesh", md))
            elif opaque:
                self._draw_mesh(md, vp, eye)
        if opaque:
            for k, (pts, color) in enumerate(frame.lines):
                if len(pts) >= 2 and nm + nk + k not in skip:
                    self._dyn_draw(pts, ctx.LINE_STRIP, vp, color)
        for k, (corners, color) in enumerate(frame.planes):
            if nm + nk + nl + k not in skip:
                see_through.append(("plane", (np.asarray(corners, float), color)))
        if not see_through or part == "opaque":
            return
        self._see_through(see_through, vp, eye, fbo)

    def _see_through(self, items: list, vp, eye, fbo) -> None:
        """Transparent meshes and planes, farthest first, blended without depth writes."""
        ctx = self.ctx

        def depth(item):
            kind, obj = item
            if kind == "plane":
                c = obj[0].mean(axis=0)
            else:
                c = (np.asarray(obj.model, float) @ np.r_[obj.gpu.center(), 1.0])[:3]
            return -float(np.linalg.norm(c - eye))

        items.sort(key=depth)  # farthest first
        ctx.enable(ctx.DEPTH_TEST)
        ctx.enable(ctx.BLEND)
        ctx.blend_func = ctx.SRC_ALPHA, ctx.ONE_MINUS_SRC_ALPHA
        fbo.depth_mask = False
        for kind, obj in items:
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
            assert view.camera is not None, f"{view_name} is not a 3-D view"
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
        """Two layers: captions, labels, HUD, aiming aid and panels first; the page box over them, so
        nothing of the scene (a marked point's label) shows through an open page."""
        ov = self.overlay
        s = frame.scale
        waiting = []  # views whose labels wait for their queries: (overlay positions, fonts, view, rect, queries)
        for view in frame.views:
            r = view.rect.scaled(s)
            if view.kind == "panel" or r.w <= 0:
                continue
            if view.title:
                panelview.view_title(ov, view.title, r, s)
            if view.kind == "fluoro" and frame.fluoro is not None:
                wl = panelview.window_level_text(frame.fluoro.window, frame.fluoro.level)
                fr, fd = self.fluoro, frame.fluoro
                panelview.fluoro_status(ov, fd.status, fd.live, fr.shown, r, s, wl, taking=bool(fr.waiting))
                fr.cue_drawn = fr.waiting or fr.cue_drawn  # the next step makes the image (FluoroRenderer.update)
                if frame.hud is not None and frame.hud.debrief_paths and self.fluoro.shown:
                    panelview.debrief_paths(ov, frame.fluoro.camera, r, frame.hud.debrief_paths, s, square=True)
            if view.camera is not None:
                found = self._labels_seen.get((r.x, r.y, r.w, r.h), [])
                if self.defer_labels and frame.labels and not all(isinstance(q, bool) for q in found):
                    # reading a query waits until the rasteriser has drawn everything queued: the
                    # labels' place in the overlay is kept, and they are put there after the rest of
                    # the overlay is laid out, so this thread works while the rasteriser does
                    waiting.append((len(ov.shapes), len(ov.glyphs.get(ov.font, ())), list(ov.glyphs), view, r, found))
                else:
                    self._view_labels(frame, view, r, self._seen(found))
            hud = frame.hud
            if hud is not None and hud.debrief_paths and view.name == frame.hud_view and view.camera is not None:
                panelview.debrief_paths(ov, view.camera, r, hud.debrief_paths, s)
            if hud is not None and view.name == hud.aim_view and view.camera is not None:
                panelview.aim(ov, view.camera, r, hud.aim_target, hud.aim_note, s)
                if hud.force_gauge:
                    panelview.force_gauge(ov, r, hud.force_gauge, s)
            if hud is not None and view.name == frame.hud_view:
                panelview.hud(ov, hud, r, s)
        for p in frame.panels:
            panelview.panel(ov, p, frame.hud, s)
        for shapes_at, glyphs_at, fonts_before, view, r, found in reversed(waiting):
            self._insert_labels(shapes_at, glyphs_at, fonts_before, frame, view, r, self._seen(found))
        if frame.doc is not None:
            W, H = frame.size[0] * s, frame.size[1] * s
            ov.flush((W, H))
            title, text, first, buttons = frame.doc
            frame.doc_shown = self.pages.draw(frame.doc_box, s, title, text, first, buttons)

    def _view_labels(self, frame: Frame, view: ViewDraw, r: Rect, seen: list[bool]) -> None:
        """The labels in sight in `view` (not behind bone or skin), each on its dark box."""
        s = frame.scale
        assert view.camera is not None  # labels are drawn in 3-D views
        for k, (pos, text, color) in enumerate(frame.labels):
            if k < len(seen) and not seen[k]:
                continue  # behind bone or skin
            x, y, z = view.camera.project(pos, r)[0]
            if -1 < z < 1 and r.contains(x, y):
                panelview.backed_label(self.overlay, text, x + 4 * s, y + 4 * s, color, s)

    def _insert_labels(self, shapes_at: int, glyphs_at: int, fonts_before: list, frame, view, r, seen) -> None:
        """Lay out a view's labels and put their shapes and glyphs where they would have gone had they
        been laid out in turn (`shapes_at`, `glyphs_at` in the overlay's lists, `fonts_before`: the fonts
        with glyphs then), so the overlay is drawn exactly as before."""
        ov = self.overlay
        font = ov.font
        shapes, glyphs = ov.shapes, ov.glyphs.get(font)
        ov.shapes = []
        ov.glyphs[font] = []
        self._view_labels(frame, view, r, seen)
        new_shapes, new_glyphs = ov.shapes, ov.glyphs[font]
        shapes[shapes_at:shapes_at] = new_shapes
        ov.shapes = shapes
        if glyphs is None:  # no text of this font after the labels' place
            glyphs = []
        glyphs[glyphs_at:glyphs_at] = new_glyphs
        ov.glyphs[font] = glyphs
        if not glyphs:
            del ov.glyphs[font]
        elif new_glyphs and font not in fonts_before:  # the font's batch goes where the labels' glyphs put it
            order = [f for f in fonts_before if f in ov.glyphs] + [font]
            order += [f for f in ov.glyphs if f not in order]
            ov.glyphs = {f: ov.glyphs[f] for f in order}

    def release(self) -> None:
        for gm in self.meshes.values():
            self._release_mesh(gm)
        self.meshes.clear()
        self.sphere.release()
        self.overlay.release()
        for o in (self.dyn_vao, self.dyn, self.mesh_prog, self.line_prog, self.id_prog):
            o.release()
        if self._fluoro is not None:
            self._fluoro.release()
            self._fluoro = None
        self.cache_views(False)
        for q in (q for qs in self._label_q for q in qs):
            if hasattr(q.mglo, "release"):
                q.mglo.release()
        self._label_q.clear()


class _Culled:
    """A big mesh's triangles in sight in its last draw (`Renderer._draw_visible`): an index buffer of
    its own, one vertex array per program, and the key (region planes, order) the list was made for."""

    def __init__(self, gm: GpuMesh):
        self.gm = gm
        self.buffer = gm.ctx.buffer(reserve=max(12, gm.tris.size), dynamic=True)  # a quarter of the whole list
        self.vaos: dict[int, moderngl.VertexArray] = {}
        self.key: tuple[bytes, int] | None = None
        self.n = 0  # triangles in the list; -1: too many left to pay (drawn whole)
        self.corners = culling.box_corners(*gm.box())
        self.tris32 = gm.tris.astype(np.uint32)
        self._depth: np.ndarray | None = None
        self._orders: dict[int, np.ndarray] = {}

    def order(self, k: int) -> np.ndarray:
        """Triangle numbers nearest-first along ORDER_DIRECTIONS[k], as GpuMesh.nearest_first stores them."""
        ids = self._orders.get(k)
        if ids is None:
            if self._depth is None:
                self._depth = self.gm.pos[self.gm.tris].astype(np.float64).mean(axis=1) @ ORDER_DIRECTIONS.T
            ids = self._orders[k] = np.argsort(-self._depth[:, k], kind="stable")
        return ids

    def vao(self, prog):
        v = self.vaos.get(prog.glo)
        if v is None:
            gm = self.gm
            attrs = [(gm.vbo_pos, "3f", "in_pos")]
            if "in_normal" in prog:
                attrs.append((gm.vbo_nrm, "3f", "in_normal"))
            v = self.vaos[prog.glo] = gm.ctx.vertex_array(prog, attrs, self.buffer)
        return v

    def release(self) -> None:
        for v in self.vaos.values():
            v.release()
        self.vaos.clear()
        self.buffer.release()


def _trs(pos, radius: float) -> np.ndarray:
    m = np.eye(4) * float(radius)
    m[3, 3] = 1.0
    m[:3, 3] = np.asarray(pos, float)
    return m

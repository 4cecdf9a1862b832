"""Cameras, picking and the control panel: turns pointer and key events into camera moves, `Picked` /
`Dragged` events and `Widget` events (thesis 3.3.4 linked views and controller; 4.5.2 dragging tissue).

Stage: input (ORDER_VIEW), after chainsim.systems.motion.input. Reads: every input event on the queue, Transform /
MeshRef / Deformable (picking, attached cameras), PackResource.layout, Settings. Writes: ViewState
(viewport rectangles and cameras, resource), WidgetState, HudState (ages messages), the `visible` flag
of MeshRef / Marker / PolyLine components of a layer switched by a toggle; emits Picked, Dragged,
LayerChanged and Widget events.

Routing: a press goes to the viewport under the cursor, which keeps the following drags and the
release (so a drag that leaves the viewport still turns its camera). In an orbit viewport with
`interactive = true`: left-drag rotates, right- or middle-drag pans, scroll zooms; a click (press and
release within CLICK_PX) picks. `interactive = false` freezes an orbit camera (it then behaves like a
fixed one). Clicks pick in orbit and fixed viewports; attached viewports (the needle-tip view) neither
move with the mouse nor pick. A drag in a "fluoro" viewport (an image of its own, the C-arm view)
becomes a `ViewTurned` event for the system that owns the image. In orbit/fixed viewports whose
camera the mouse does not move, a left press on a surface starts a `Dragged` sequence (grabbing
tissue, thesis 4.5.2). Procedures may move any camera themselves: `ViewState.get(name).camera` is an
OrbitCamera (set yaw/pitch/distance/target, then call `update_eye()`).

Widgets: clicks, drags and shortcut keys on the panel produce `Widget(name, value)` events that this
system emits directly on the event queue (not through PendingInput, so a recording holds the clicks
once and a replay reproduces the widget events from them). Scripted Widget events, released by the
input system, go through the same `apply_widget` + layer effects, so both have the same effect.
Toggle `layer` conventions: "NAME" shows/hides entities of layer NAME (and the pack's [planes] when
NAME is "planes"); "view:NAME" shows/hides viewport NAME; "xray:NAME" draws layer NAME see-through;
"wire:NAME" draws layer NAME as its links (wireframe, thesis Figs 5.6-5.7).
Key "f1" opens or closes the key page, "escape" closes an open page.

Pages (chainsim.systems.view.ui.docbox): while a page, the key overlay or a notice is open over the main
view, the box takes the pointer - its footer buttons turn pages or close it, the wheel scrolls it -
and a click on the main view around it does nothing, so nothing lands on the face underneath.
The panel and the other views keep working.

Framing: a viewport with `fit = true` is placed (its yaw and pitch kept) so the box around the
visible meshes and their pull paths fills it, clear of its caption and of the step text
(`frame_view`, chainsim.systems.view.ui.viewports.fit_orbit); again after a resize unless the trainee
moved it. Help: the `help` widget opens the current step's page, else the last shown, else the
pack's first; the key page (F1) leads on to the pages with its "Help pages >" button.

Camera presets: a button named "camera:front", "camera:side", "camera:below" or "camera:reset"
(with a key, like any widget) moves the main orbit view: front (facing +Y, the face), side (from
the subject's left, again for the right), below (from under the chin), or back to the layout's view.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import Marker, MeshRef, PolyLine, Transform, to_world
from chainsim.components.hud import HudState
from chainsim.components.input_events import Key, MouseButton, MouseDrag, MouseMove, PickPoint, Resize, Scroll, Widget
from chainsim.components.resources import EntityIndex, InputState, PackResource, Settings
from chainsim.components.stages import ORDER_VIEW
from chainsim.components.view_events import Dragged, LayerChanged, Picked, ViewTurned, WidgetRefused
from chainsim.systems.engine.errors import UserError
from chainsim.systems.tissue.deformable import Pull
from chainsim.systems.view.picking import pick, snap
from chainsim.systems.view.ui import docbox
from chainsim.systems.view.ui import widgets as wd
from chainsim.systems.view.ui.viewports import (
    KINDS_3D,
    Camera,
    OrbitCamera,
    Rect,
    attached_camera,
    fit_orbit,
    layout_rects,
    orbit_from_table,
)

CLICK_PX = 4.0  # a press and release closer than this (total travel) is a click, not a drag


@dataclass(slots=True)
class Viewport:
    name: str
    kind: str
    spec: dict
    rect: Rect
    camera: Camera | None
    visible: bool
    interactive: bool
    home: tuple | None = None  # (target, distance, yaw, pitch) the view was framed at; camera:reset returns here

    @property
    def is_3d(self) -> bool:
        return self.kind in KINDS_3D

    @property
    def mouse_camera(self) -> bool:
        """Whether mouse drags move this viewport's camera."""
        return self.kind == "orbit" and self.interactive

    @property
    def picks(self) -> bool:
        """Whether clicks pick here: orbit and fixed views; attached views only show (thesis 3.3.4)."""
        return self.kind in ("orbit", "fixed")


@dataclass(slots=True)
class ViewState:
    """Viewports with their cameras and pixel rectangles (window pixels), layer switches, pointer capture."""

    viewports: list[Viewport] = field(default_factory=list)
    size: tuple[int, int] = (1280, 800)
    layers: dict[str, bool] = field(default_factory=dict)
    xray: set[str] = field(default_factory=set)
    wire: set[str] = field(default_factory=set)
    panels: dict[str, list[wd.Placed]] = field(default_factory=dict)
    hover: str = ""  # widget under the pointer (its `help` is shown in the panel)
    # pointer capture (runtime)
    active: str | None = None
    press: tuple[float, float, str] | None = None
    travel: float = 0.0
    widget: wd.Placed | None = None
    grab: tuple | None = None  # (viewport, entity, name, triangle, grab_point)
    scene_box: tuple | None = None  # (lo, hi) world mm: what views with `fit = true` frame
    # an enlarged view (`enlarge:NAME` widget): 1 = it takes the main view's place and the main view
    # its own, 2 = it fills the window; 0 = the layout as written
    enlarged: str = ""
    enlarge: int = 0
    # the C-arm monitor's window/level (a right-drag in its view; a right-click resets it): the grey
    # window's width as a multiple of the automatic one, and its centre moved by this fraction of the
    # automatic width
    xray_window: float = 1.0
    xray_level: float = 0.0

    def get(self, name: str) -> Viewport | None:
        for vp in self.viewports:
            if vp.name == name:
                return vp
        return None

    def at(self, x: float, y: float) -> Viewport | None:
        """The visible viewport under a window point (the last listed wins where they overlap)."""
        for vp in reversed(self.viewports):
            if vp.visible and vp.rect.contains(x, y):
                return vp
        return None

    def layer_visible(self, layer: str) -> bool:
        return self.layers.get(layer, True)


def main_view(vs: ViewState) -> Viewport | None:
    """The view that shows the step text, messages and pages: the first visible orbit view on screen,
    else the first visible 3-D view; while another view is more than MAIN_GIVES_WAY times its size (an
    X-ray enlarged into its place, or over the whole window) that one, so the pages and the step text are
    not squeezed into a small inset."""
    on_screen = [vp for vp in vs.viewports if vp.visible and vp.kind != "panel" and vp.rect.w > 0 and vp.rect.h > 0]
    pool = on_screen or [vp for vp in vs.viewports if vp.visible and vp.kind != "panel"]  # before the first layout
    shown = [vp for vp in pool if vp.is_3d]
    views = [vp for vp in shown if vp.kind == "orbit"] or shown
    biggest = max(pool, key=_area) if pool else None
    if views and (biggest is None or _area(biggest) <= MAIN_GIVES_WAY * _area(views[0])):
        return views[0]
    return biggest


#: the 3-D view gives the step text and pages to a view this many times its size (an X-ray enlarged into
#: its place: the 3-D view is then the small inset)
MAIN_GIVES_WAY = 2.0


def _area(vp: Viewport) -> float:
    return float(vp.rect.w) * float(vp.rect.h)


def _xyz(p) -> tuple[float, float, float]:
    """A point as the three plain floats the view events carry."""
    return (float(p[0]), float(p[1]), float(p[2]))


CAMERA_PRESETS = ("front", "side", "below", "reset")


def camera_preset(vp: Viewport, preset: str) -> None:
    """Move an orbit camera to a preset around the layout's target, or around where the view was framed
    (`fit = true`; see the module docstring)."""
    cam = vp.camera
    if not isinstance(cam, OrbitCamera):
        return
    spec = vp.spec
    if vp.home is not None:
        cam.target, cam.distance = np.asarray(vp.home[0], float).copy(), float(vp.home[1])
        home_yaw, home_pitch = vp.home[2], vp.home[3]
    else:
        cam.target = np.asarray(spec.get("target", (0, 0, 0)), float).copy()
        cam.distance = float(spec.get("distance", cam.distance))
        home_yaw, home_pitch = float(spec.get("yaw", 0.0)), float(spec.get("pitch", 0.0))
    if preset == "front":
        cam.yaw, cam.pitch = 0.0, 0.0
    elif preset == "side":  # from the subject's left (eye at -X); pressed again, from the right
        cam.yaw, cam.pitch = (270.0 if abs(cam.yaw - 90.0) < 1e-6 and abs(cam.pitch) < 1e-6 else 90.0), 0.0
    elif preset == "below":  # from under the chin, looking up at the skull base
        cam.yaw, cam.pitch = 0.0, -80.0
    else:
        cam.yaw, cam.pitch = home_yaw, home_pitch
    cam.update_eye()


#: free pixels along the top of a framed view: its caption, and in the main view the step text too
FIT_TOP_MAIN = 92.0
FIT_TOP = 30.0
FIT_MARGIN = 12.0


def frame_view(vs: ViewState, vp: Viewport, lo, hi) -> None:
    """Place an orbit or fixed view's camera (its yaw and pitch kept) so the box lo..hi fills the view,
    clear of its caption and, in the main view, of the step text (chainsim.systems.view.ui.viewports.fit_orbit)."""
    if vp.kind not in ("orbit", "fixed") or not isinstance(vp.camera, OrbitCamera) or vp.rect.w < 2 or vp.rect.h < 2:
        return
    top = FIT_TOP_MAIN if vp is main_view(vs) else FIT_TOP
    fit_orbit(vp.camera, vp.rect, lo, hi, FIT_MARGIN, top)


def _at_home(vp: Viewport) -> bool:
    cam = vp.camera
    if vp.home is None or not isinstance(cam, OrbitCamera):
        return False
    t, d, yaw, pitch = vp.home
    return bool(np.allclose(cam.target, t)) and abs(cam.distance - d) < 1e-9 and (cam.yaw, cam.pitch) == (yaw, pitch)


def fit_views(vs: ViewState, resized: bool = False) -> None:
    """Frame the scene box in every view whose layout says `fit = true`. After a resize only the views
    the mouse does not move, and mouse-driven ones still where they were framed, are framed again."""
    if vs.scene_box is None:
        return
    for vp in vs.viewports:
        if not vp.spec.get("fit") or not isinstance(vp.camera, OrbitCamera):
            continue
        if resized and vp.mouse_camera and not _at_home(vp):
            continue  # the trainee moved this view: leave it where they put it
        frame_view(vs, vp, *vs.scene_box)
        cam = vp.camera
        vp.home = (cam.target.copy(), cam.distance, cam.yaw, cam.pitch)


def scene_bounds(app: App) -> tuple[np.ndarray, np.ndarray] | None:
    """World box of the visible meshes at rest and of the paths their scripted pulls will take
    (so a pulled element stays in view); None for a scene without meshes."""
    pack = app.resource(PackResource).pack
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    with app.active():
        for ent, ref in esper.get_component(MeshRef):
            if not ref.visible:
                continue
            tr = esper.try_component(ent, Transform)
            pts = [to_world(tr, pack.mesh(ref.mesh).vertices)]
            pull = esper.try_component(ent, Pull)
            if pull is not None and len(pull.waypoints):
                way = np.asarray(pull.waypoints, float).reshape(-1, 3)
                pts.append(way if pull.frame == "world" else to_world(tr, way))
            w = np.vstack(pts)
            if not len(w):
                continue
            lo, hi = np.minimum(lo, w.min(axis=0)), np.maximum(hi, w.max(axis=0))
    if not np.all(np.isfinite(lo)):
        return None
    return lo, hi


def page_buttons(h: HudState) -> tuple[str, ...]:
    """The footer buttons of what the page box shows now (as chainsim.game.render.render_system draws them):
    the key page leads on to the pack's help pages."""
    if h.notice:
        return ()
    if h.doc_name == "keys":
        return docbox.KEY_PAGE_BUTTONS
    return docbox.PAGE_BUTTONS


def open_help(h: HudState, docs: list[str], page: str | None = None) -> None:
    """Open a help page: `page`, else the current step's, else the one shown last, else the pack's
    first (a pack without steps still reaches its pages)."""
    if page is None and not h.step_doc and (not h.doc_name or h.doc_name == "keys") and docs:
        page = docs[0]
    h.open_doc(page)


def first_panel(vs: ViewState) -> str:
    return next((vp.name for vp in vs.viewports if vp.kind == "panel"), "")


#: a right-drag in the C-arm view: window width x exp(dx * this), per pixel
WINDOW_PER_PX = 0.01
#: ... and level moved by dy * this (fractions of the automatic window), per pixel
LEVEL_PER_PX = 0.004


def relayout(vs: ViewState, widgets: list[dict], width: int, height: int) -> None:
    vs.size = (int(width), int(height))
    rects = layout_rects([vp.spec for vp in vs.viewports], vs.size[0], vs.size[1])
    big = vs.get(vs.enlarged) if vs.enlarge else None
    main = main_view(vs)
    if big is not None and vs.enlarge == 2:  # the whole window: every other view gives way
        rects = {name: (Rect(0, 0, vs.size[0], vs.size[1]) if name == big.name else Rect(0, 0, 0, 0)) for name in rects}
    elif big is not None and main is not None and main is not big:  # the two swap places
        rects[big.name], rects[main.name] = rects[main.name], rects[big.name]
    for vp in vs.viewports:
        vp.rect = rects[vp.name]
    fp = first_panel(vs)
    vs.panels = {
        vp.name: wd.place(wd.panel_widgets(widgets, vp.name, fp), vp.rect) for vp in vs.viewports if vp.kind == "panel"
    }


def build_view_state(layout: dict, size: tuple[int, int]) -> ViewState:
    vs = ViewState()
    for spec in layout.get("viewports", []):
        kind = spec["kind"]
        cam = orbit_from_table(spec) if kind in ("orbit", "fixed", "attached") else None
        vs.viewports.append(
            Viewport(
                spec["name"],
                kind,
                spec,
                Rect(0, 0, 1, 1),
                cam,
                bool(spec.get("visible", True)),
                bool(spec.get("interactive", True)),
            )
        )
    relayout(vs, layout.get("widgets", []), *size)
    return vs


def refresh_cameras(app: App, vs: ViewState) -> None:
    """Place attached cameras on their entities (call before drawing or picking)."""
    index = app.get_resource(EntityIndex)
    for vp in vs.viewports:
        if vp.kind != "attached" or index is None:
            continue
        ent = index.get(vp.spec.get("attach", ""))
        tr = esper.try_component(ent, Transform) if ent is not None else None
        if tr is None:
            continue
        vp.camera = attached_camera(
            tr.position,
            tr.rotation,
            tr.scale,
            vp.spec.get("offset", (0, 0, 0)),
            float(vp.spec.get("fov", 40.0)),
            float(vp.spec.get("near", 1.0)),
            float(vp.spec.get("far", 5000.0)),
        )


def set_layer(app: App, layer: str, visible: bool) -> None:
    """Show or hide a visibility group (see the module docstring for the `view:` and `xray:` forms)."""
    vs: ViewState = app.resource(ViewState)
    if layer.startswith("view:"):
        vp = vs.get(layer[5:])
        if vp is not None:
            vp.visible = bool(visible)
    elif layer.startswith("xray:"):
        (vs.xray.add if visible else vs.xray.discard)(layer[5:])
    elif layer.startswith("wire:"):
        (vs.wire.add if visible else vs.wire.discard)(layer[5:])
    else:
        vs.layers[layer] = bool(visible)
        for comp_type in (MeshRef, Marker, PolyLine):
            for _, comp in esper.get_component(comp_type):
                if comp.layer == layer:
                    comp.visible = bool(visible)
    app.events.emit(LayerChanged(layer, bool(visible)))


class ViewSystem:
    """The system object: holds its event reader and the events it emitted itself."""

    def __init__(self, app: App):
        self.reader = app.events.reader(None)
        self.own: list = []

    def emit(self, app: App, ev) -> None:
        self.own.append(ev)
        app.events.emit(ev)

    # -- widgets ---------------------------------------------------------------------------------
    def use_widget(self, app: App, name: str, value) -> None:
        st: wd.WidgetState = app.resource(wd.WidgetState)
        if not st.enabled(name):
            return
        self.emit(app, Widget(name, value))
        self.apply(app, name, value)

    def apply(self, app: App, name: str, value) -> None:
        st: wd.WidgetState = app.resource(wd.WidgetState)
        if not wd.apply_widget(st, name, value):
            return
        if name == "help" or name.startswith("docs:"):
            h: HudState = app.resource(HudState)
            page = name[5:] if name.startswith("docs:") else None
            if h.doc_open and (page is None or page == h.doc_name):
                h.close_doc()
            else:
                open_help(h, list(app.resource(PackResource).pack.section("docs")), page)
        if name.startswith("enlarge:"):
            vs = app.resource(ViewState)
            step = 0 if vs.enlarged != name[8:] else vs.enlarge
            vs.enlarged, vs.enlarge = name[8:], (step + 1) % 3
            relayout(vs, app.resource(PackResource).layout.get("widgets", []), *vs.size)
            fit_views(vs, resized=True)
        if name.startswith("camera:") and name[7:] in CAMERA_PRESETS:
            vs = app.resource(ViewState)
            vp = main_view(vs)
            if vp is not None and vp.is_3d:
                camera_preset(vp, name[7:])
                if vp.spec.get("fit") and vs.scene_box is not None:  # framed for the view's size now
                    frame_view(vs, vp, *vs.scene_box)
                    if name == "camera:reset":
                        cam = vp.camera
                        if isinstance(cam, OrbitCamera):  # the views frame_view places
                            vp.home = (cam.target.copy(), cam.distance, cam.yaw, cam.pitch)
        spec = st.specs.get(name)
        if spec is not None and spec["kind"] == "toggle" and spec.get("layer"):
            set_layer(app, spec["layer"], bool(st.values[name]))

    # -- pointer ---------------------------------------------------------------------------------
    def ray(self, vp: Viewport, x: float, y: float):
        # window events carry whole pixels: aim through the pixel centre, as the renderer samples it
        assert vp.camera is not None  # only 3-D views are aimed through
        return vp.camera.ray(x + 0.5, y + 0.5, vp.rect)

    # -- the page box ----------------------------------------------------------------------------
    def page_open(self, app: App) -> bool:
        h = app.resource(HudState)
        return bool(h.notice) or h.doc_open

    def page_box(self, app: App, vs: ViewState):
        main = main_view(vs)
        return docbox.box(main.rect) if main is not None and self.page_open(app) else None

    def page_button(self, app: App, name: str) -> None:
        h: HudState = app.resource(HudState)
        if name == "close":
            h.close_doc()
            return
        names = list(app.resource(PackResource).pack.section("docs"))
        if name == "docs":  # from the key page on to the help pages
            open_help(h, names)
            return
        if h.doc_name in names:
            k = names.index(h.doc_name) + (1 if name == "next" else -1)
            if 0 <= k < len(names):
                h.open_doc(names[k])

    def press(self, app: App, vs: ViewState, ev: MouseButton) -> None:
        vp = vs.at(ev.x, ev.y)
        vs.active = vp.name if vp else None
        vs.press = (ev.x, ev.y, ev.button)
        vs.travel = 0.0
        vs.widget = None
        vs.grab = None
        if vp is None:
            return
        b = self.page_box(app, vs)
        if b is not None and vp is main_view(vs):  # the page takes the pointer over the main view
            vs.active = PAGE
            button = docbox.button_at(b, ev.x, ev.y, page_buttons(app.resource(HudState)))
            if button is not None and ev.button == "left":
                self.page_button(app, button)
            return
        if vp.kind == "panel":
            p = wd.hit(vs.panels.get(vp.name, []), ev.x, ev.y)
            st: wd.WidgetState = app.resource(wd.WidgetState)
            if p is not None and ev.button == "left" and st.enabled(p.spec["name"]):
                vs.widget = p
                self.use_widget(app, p.spec["name"], wd.click_value(p, ev.x, st.values.get(p.spec["name"])))
            elif p is not None and ev.button == "left":
                self.emit(app, WidgetRefused(p.spec["name"]))
        elif vp.picks and vp.camera is not None and not vp.mouse_camera and ev.button == "left":
            o, d = self.ray(vp, ev.x, ev.y)
            hit = pick(app, o, d)
            if hit is not None:
                gp = _xyz(hit.point)
                vs.grab = (vp.name, hit.entity, hit.name, hit.triangle, gp)
                self.emit(app, Dragged(vp.name, hit.entity, hit.name, "start", hit.triangle, gp, gp, ev.button))

    def drag_point(self, vs: ViewState, vp: Viewport, x: float, y: float):
        o, d = self.ray(vp, x, y)
        assert vs.grab is not None and vp.camera is not None  # called while a grab in a 3-D view is on
        gp = np.asarray(vs.grab[4])
        n = vp.camera.forward
        denom = float(d @ n)
        t = float((gp - o) @ n) / denom if abs(denom) > 1e-12 else 0.0
        return _xyz(o + t * d)

    def drag(self, app: App, vs: ViewState, ev: MouseDrag) -> None:
        vs.travel += abs(ev.dx) + abs(ev.dy)
        if vs.active == PAGE:
            return
        vp = vs.get(vs.active) if vs.active else None
        if vp is None:
            return
        if vp.kind == "panel":
            if vs.widget is not None and vs.widget.spec["kind"] in ("slider", "dial"):
                st: wd.WidgetState = app.resource(wd.WidgetState)
                name = vs.widget.spec["name"]
                cur = st.values.get(name)
                new = wd.drag_value(vs.widget, ev.x, ev.dx, cur)
                if new != cur:
                    self.use_widget(app, name, new)
        elif vs.grab is not None:
            g = vs.grab
            self.emit(
                app, Dragged(vp.name, g[1], g[2], "move", g[3], g[4], self.drag_point(vs, vp, ev.x, ev.y), ev.button)
            )
        elif vp.mouse_camera and isinstance(vp.camera, OrbitCamera):
            if ev.button == "left":
                vp.camera.rotate(ev.dx, ev.dy)
            else:
                vp.camera.pan(ev.dx, ev.dy, vp.rect)
        elif vp.kind == "fluoro" and ev.button == "right":  # window/level, as on a fluoroscopy monitor
            vs.xray_window = float(np.clip(vs.xray_window * np.exp(ev.dx * WINDOW_PER_PX), 0.05, 4.0))
            vs.xray_level = float(np.clip(vs.xray_level + ev.dy * LEVEL_PER_PX, -1.5, 1.5))
        elif vp.kind == "fluoro" and vp.interactive:
            self.emit(app, ViewTurned(vp.name, float(ev.dx), float(ev.dy), ev.button))

    def release(self, app: App, vs: ViewState, ev: MouseButton) -> None:
        if vs.active == PAGE:
            vs.active, vs.press, vs.widget, vs.grab, vs.travel = None, None, None, None, 0.0
            return
        vp = vs.get(vs.active) if vs.active else None
        if vs.press is not None:
            vs.travel = max(vs.travel, abs(ev.x - vs.press[0]) + abs(ev.y - vs.press[1]))
        if vp is not None and vp.kind == "fluoro" and ev.button == "right" and vs.travel <= CLICK_PX:
            vs.xray_window, vs.xray_level = 1.0, 0.0  # a right-click without a drag: window/level reset
        if vp is not None and vp.is_3d and vp.camera is not None:
            if vs.grab is not None:
                g = vs.grab
                self.emit(
                    app, Dragged(vp.name, g[1], g[2], "end", g[3], g[4], self.drag_point(vs, vp, ev.x, ev.y), ev.button)
                )
            if vs.travel <= CLICK_PX and vp.picks:
                o, d = self.ray(vp, ev.x, ev.y)
                hit = pick(app, o, d)
                if hit is not None:
                    self.emit(
                        app,
                        Picked(vp.name, hit.entity, hit.name, hit.triangle, _xyz(hit.point), ev.button),
                    )
        vs.active, vs.press, vs.widget, vs.grab, vs.travel = None, None, None, None, 0.0

    def scroll_widget(self, app: App, vs: ViewState, vp: Viewport, ev: Scroll) -> None:
        """The wheel over a slider or dial steps it (up = more)."""
        p = wd.hit(vs.panels.get(vp.name, []), ev.x, ev.y)
        st: wd.WidgetState = app.resource(wd.WidgetState)
        if p is None or p.spec["kind"] not in ("slider", "dial") or not st.enabled(p.spec["name"]) or ev.dy == 0:
            return
        name = p.spec["name"]
        cur = st.values.get(name)
        new = wd.stepped(p.spec, cur, 1 if ev.dy > 0 else -1)
        if new != cur:
            self.use_widget(app, name, new)

    def pick_point(self, app: App, ev: PickPoint) -> None:

        index: EntityIndex = app.resource(EntityIndex)
        ent = index.get(ev.entity)
        if ent is None:
            raise UserError(
                f"pick event: no entity '{ev.entity}' in this scene; entities: {', '.join(sorted(index.by_name))}"
            )
        hit = snap(app, ent, ev.point)
        if hit is None:
            raise UserError(f"pick event: entity '{ev.entity}' has no triangle mesh to pick on")
        self.emit(app, Picked("", ent, hit.name, hit.triangle, _xyz(hit.point), ev.button))

    # -- the system ------------------------------------------------------------------------------
    def __call__(self, app: App) -> None:
        vs: ViewState = app.resource(ViewState)
        app.resource(HudState).age(app.time.frame_dt)
        events = self.reader.read()
        own, self.own = self.own, []
        layout = app.resource(PackResource).layout
        refreshed = False
        for ev in events:
            if any(ev is o for o in own):
                continue
            if isinstance(ev, (MouseButton, MouseDrag, PickPoint)) and not refreshed:
                refresh_cameras(app, vs)
                refreshed = True
            if isinstance(ev, Resize):
                relayout(vs, layout.get("widgets", []), ev.width, ev.height)
                fit_views(vs, resized=True)
            elif isinstance(ev, MouseButton):
                (self.press if ev.pressed else self.release)(app, vs, ev)
            elif isinstance(ev, MouseDrag):
                self.drag(app, vs, ev)
            elif isinstance(ev, MouseMove):
                vp = vs.at(ev.x, ev.y)
                placed = vs.panels.get(vp.name, []) if vp is not None and vp.kind == "panel" else []
                under = next((p for p in reversed(placed) if p.rect.contains(ev.x, ev.y)), None)
                vs.hover = under.spec["name"] if under is not None else ""
            elif isinstance(ev, Scroll):
                vp = vs.at(ev.x, ev.y)
                b = self.page_box(app, vs)
                if b is not None and vp is main_view(vs):
                    h = app.resource(HudState)
                    if b.contains(ev.x, ev.y) and not h.notice and ev.dy:
                        h.doc_scroll = max(0, h.doc_scroll + (-3 if ev.dy > 0 else 3))
                elif vp is not None and vp.mouse_camera and isinstance(vp.camera, OrbitCamera):
                    vp.camera.zoom(ev.dy)
                elif vp is not None and vp.kind == "panel":
                    self.scroll_widget(app, vs, vp, ev)
            elif isinstance(ev, Key) and ev.pressed:
                h = app.resource(HudState)
                if ev.key == "f1":
                    if h.doc_open and h.doc_name == "keys":
                        h.close_doc()
                    else:
                        h.open_doc("keys")
                elif ev.key == "escape" and h.doc_open:
                    h.close_doc()
                if h.doc_open and ev.key in DOC_SCROLL:
                    h.doc_scroll = max(0, h.doc_scroll + DOC_SCROLL[ev.key])
                st: wd.WidgetState = app.resource(wd.WidgetState)
                for w in layout.get("widgets", []):
                    if w.get("key") and w["key"].lower() == ev.key and w["kind"] in wd.INTERACTIVE:
                        if st.enabled(w["name"]):
                            self.use_widget(app, w["name"], wd.key_value(w, st.values.get(w["name"])))
            elif isinstance(ev, Widget):
                self.apply(app, ev.name, ev.value)
            elif isinstance(ev, PickPoint):
                self.pick_point(app, ev)
        self.own.extend(o for o in own if not any(o is e for e in events))


DOC_SCROLL = {"pagedown": 12, "pageup": -12}
PAGE = "\x00page"  # ViewState.active while the page box holds the pointer


def default_layout(app: App) -> dict:
    """One orbit viewport framing every mesh, for scenes that name no layout."""

    pack = app.resource(PackResource).pack
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    with app.active():
        for ent, ref in esper.get_component(MeshRef):
            tr = esper.try_component(ent, Transform)
            w = to_world(tr, pack.mesh(ref.mesh).vertices)
            lo, hi = np.minimum(lo, w.min(axis=0)), np.maximum(hi, w.max(axis=0))
    if not np.all(np.isfinite(lo)):
        lo, hi = np.full(3, -100.0), np.full(3, 100.0)
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1.0)
    fov = 40.0
    dist = 1.15 * radius / math.sin(math.radians(fov / 2))
    vp = {
        "name": "main",
        "kind": "orbit",
        "rect": [0.0, 0.0, 1.0, 1.0],
        "title": "",
        "target": (lo + hi) / 2,
        "distance": dist,
        "yaw": 30.0,
        "pitch": 25.0,
        "fov": fov,
        "near": max(dist / 1000, 1e-3),
        "far": dist * 10 + radius,
        "attach": "",
        "offset": np.zeros(3),
        "visible": True,
        "interactive": True,
    }
    return {"viewports": [vp], "widgets": []}


def plugin(app: App) -> None:
    pres: PackResource = app.resource(PackResource)
    layout = pres.layout
    if not layout.get("viewports"):
        layout = {"viewports": default_layout(app)["viewports"], "widgets": layout.get("widgets", [])}
    width, height = app.resource(Settings).get("window_size", (1280, 800))
    size = (int(width), int(height))
    app.resource(InputState).window_size = size
    vs = app.insert_resource(build_view_state(layout, size))
    vs.scene_box = scene_bounds(app)
    fit_views(vs)
    st = app.insert_resource(wd.WidgetState.from_layout(layout.get("widgets", [])))
    steps = pres.pack.section("steps")
    hud = HudState()
    if steps:
        hud.step_title, hud.step_instruction = steps[0].get("title", ""), steps[0].get("instruction", "")
        hud.step_doc = steps[0].get("docs", "")
    app.insert_resource(hud)
    vs.layers.setdefault("planes", False)
    with app.active():
        for w in layout.get("widgets", []):
            if w["kind"] == "toggle" and w.get("layer"):
                set_layer(app, w["layer"], bool(st.values[w["name"]]))
    app.add_system("input", ViewSystem(app), order=ORDER_VIEW, name="view")

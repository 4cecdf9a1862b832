"""Deformation: serves grab / release / cut / add-link requests on deformable bodies with ChainMail.

Stage: simulation (ORDER_DEFORMATION; the scripted puller just before it). Reads GrabRequest,
ReleaseRequest, CutRequest, AddLinksRequest (chainsim.systems.tissue.events), Widget events (to start pulls) and
the view system's Dragged events (with `deformable.drag`, a mouse drag on a body pulls the element
nearest the grab point; off by default so a procedure's own tools are the only hands on the tissue).
Writes the soft body's positions, dirty ids, version, held elements and alive links (Deformable.body),
emits Deformed.

Each grab runs one Generalised ChainMail cascade (thesis 5.2.3) from the grabbed elements, then the
relaxation of 5.2.5 over the elements that moved (grabbed, held and fixed elements stay put), then, for
a material with `exact = true`, the exact-limit pass (chainsim.systems.engine.kernels.exact). Cuts mark links
dead (thesis 4.5.2); the renderer sees moved vertices through `dirty`.

Installed only when some entity is deformable: a `deformable` table, or `simulation.kind` "surface" /
"volume" on a mesh entity (which gets a default `deformable`, material = its mesh material). A scene
of rigid bodies gets no deformation system at all.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import MeshRef, Name, Simulation, Transform
from chainsim.components.events import EventReader
from chainsim.components.hud import HudState
from chainsim.components.input_events import Widget
from chainsim.components.resources import EntityIndex, PackResource
from chainsim.components.stages import ORDER_DEFORMATION
from chainsim.components.view_events import Dragged
from chainsim.systems.engine.bodies.chainmail import relax_moved  # noqa: F401  (re-exported for the older callers)
from chainsim.systems.engine.bodies.soft import SoftBody
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels import topology
from chainsim.systems.tissue.deformable import Deformable, Pull, setup_deformable, use_model
from chainsim.systems.tissue.events import (
    FRAMES,
    AddLinksRequest,
    CutRequest,
    Deformed,
    GrabRequest,
    ReleaseRequest,
    ResetRequest,
    as_points,
)

ORDER_PULL = ORDER_DEFORMATION - 10


@dataclass(slots=True)
class DeformationState:
    """Event cursors of the deformation systems, and counters for summaries."""

    requests: EventReader[Any]  # one cursor over all events, so requests are served in emission order
    widgets: EventReader[Widget]
    drag_type: type | None = None  # view_events.Dragged, when the view system is part of the build
    dragging: dict = field(default_factory=dict)  # entity -> (element, its local start, world grab point)
    errors: list = field(default_factory=list)
    announced: bool = False  # the HUD has said which model `auto` chose, and why


# -- frames --------------------------------------------------------------------------------------


def to_local(ent: int, pts: np.ndarray, frame: str) -> np.ndarray:
    if frame not in FRAMES:
        raise ValueError(f"frame must be one of {', '.join(FRAMES)}, got {frame!r}")
    if frame == "local":
        return pts

    tr = esper.try_component(ent, Transform)
    return pts if tr is None else tr.inverse_apply(pts)


def _to_world(ent: int, pts: np.ndarray) -> np.ndarray:

    tr = esper.try_component(ent, Transform)
    return pts if tr is None else tr.apply(pts)


def _entity(app: App, ref) -> int | None:
    if isinstance(ref, str):
        index = app.get_resource(EntityIndex)
        return index.get(ref) if index is not None else None
    return int(ref)


# -- operations (also used directly by tools and tests) -------------------------------------------


def grab(d: Deformable, ids, targets_local: np.ndarray, hold: bool = True) -> np.ndarray:
    """Move `ids` to local `targets`, cascade, relax (and keep every link inside its limits with an exact
    material); returns the ids that changed."""
    soft = d.body
    ids = np.atleast_1d(np.asarray(ids, dtype=np.int64))
    n = soft.n
    if len(ids) == 0 or ids.min() < 0 or ids.max() >= n:
        raise ValueError(f"element ids must be in 0..{n - 1}")
    targets = np.asarray(targets_local, dtype=np.float64).reshape(len(ids), 3)
    if soft.dynamic:
        return _grab_body(soft, ids, targets, hold)
    b = soft.model_body  # the settings are the ones a pack, a tool or a test last set
    b.relax_iterations, b.relax_step, b.order, b.depth, b.exact = (
        soft.relax_iterations,
        d.relax_step,
        d.order,
        d.depth,
        soft.exact,
    )
    b.fixed, b.held = soft.fixed, soft.held
    changed = b.move(ids, targets, hold=hold)
    soft.held = b.held
    if len(changed):
        soft.changed(changed)
    return changed


def release(d: Deformable, ids=None) -> None:
    soft = d.body
    if ids is None:
        keep = np.zeros(len(soft.held), dtype=np.bool_)
    else:
        keep = ~np.isin(soft.held, np.asarray(ids, dtype=np.int64))
    body = soft.model_body
    if soft.dynamic and len(soft.held_targets) == len(soft.held):
        soft.held_targets = soft.held_targets[keep]
        body.grab(soft.held[keep], soft.held_targets) if keep.any() else body.release()
    soft.held = soft.held[keep]
    if body is not None and not soft.dynamic:
        body.held = soft.held


def _grab_body(soft: SoftBody, ids: np.ndarray, targets: np.ndarray, hold: bool) -> np.ndarray:
    """xpbd / projective: the elements are held at their targets; the body moves on its next step."""
    old = ~np.isin(soft.held, ids)
    soft.held = np.concatenate([soft.held[old], ids])
    soft.held_targets = np.concatenate([soft.held_targets[old], targets])
    soft.model_body.grab(soft.held, soft.held_targets)
    if not hold:  # a one-off move: held for the next step only
        soft.transient = np.union1d(soft.transient, ids)
    return np.zeros(0, dtype=np.int64)


def step_body(d: Deformable, dt: float) -> int:
    """Advance an xpbd / projective body one simulation step; returns how many elements moved."""
    soft = d.body
    try:
        soft.model_body.step(dt)
    except UserError as e:  # diverged: positions were restored; say so once and let go of the grab
        release(d)
        raise ValueError(str(e)) from None
    if len(soft.transient):
        release(d, soft.transient)
        soft.transient = np.zeros(0, dtype=np.int64)
    moved = soft.model_body.moved
    if len(moved):
        soft.changed(moved)
    return len(moved)


def cut(d: Deformable, ent: int, req: CutRequest) -> int:
    """Kill the links a blade crosses (4.5.2); returns how many were cut."""

    soft = d.body
    before = int(np.count_nonzero(soft.alive))
    if soft.dynamic:
        return _cut_body(soft, ent, req)
    if req.polyline is not None:
        pts = to_local(ent, as_points(req.polyline, "CutRequest.polyline"), req.frame)
        if len(pts) < 2:
            raise ValueError("CutRequest.polyline: needs at least 2 points")
        topology.cut_path(soft.positions, soft.graph, pts, **_blade_kwargs(ent, req))
    else:
        if req.p0 is None or req.p1 is None:
            raise ValueError("CutRequest: give p0 and p1, or a polyline")
        p0 = to_local(ent, as_points(req.p0, "CutRequest.p0"), req.frame)[0]
        p1 = to_local(ent, as_points(req.p1, "CutRequest.p1"), req.frame)[0]
        topology.cut_segment(soft.positions, soft.graph, p0, p1, **_blade_kwargs(ent, req))
    cut_count = before - int(np.count_nonzero(soft.alive))
    if cut_count:
        soft.version += 1
    return cut_count


def _cut_body(soft: SoftBody, ent: int, req: CutRequest) -> int:
    """xpbd / projective: the blade removes the links it crosses and the constraints built on them."""
    kw = _blade_kwargs(ent, req)
    if req.polyline is not None:
        pts = to_local(ent, as_points(req.polyline, "CutRequest.polyline"), req.frame)
        if len(pts) < 2:
            raise ValueError("CutRequest.polyline: needs at least 2 points")
        n = soft.model_body.cut_path(pts, **kw)
    else:
        if req.p0 is None or req.p1 is None:
            raise ValueError("CutRequest: give p0 and p1, or a polyline")
        p0 = to_local(ent, as_points(req.p0, "CutRequest.p0"), req.frame)[0]
        p1 = to_local(ent, as_points(req.p1, "CutRequest.p1"), req.frame)[0]
        n = soft.model_body.cut(p0, p1, **kw)
    if n:
        soft.version += 1
    return n


def _blade_kwargs(ent: int, req: CutRequest) -> dict:
    kw = {}
    if req.normal is not None:
        nrm = as_points(req.normal, "CutRequest.normal")[0]
        if req.frame == "world":
            tr = esper.try_component(ent, Transform)
            if tr is not None:
                nrm = np.linalg.inv(tr.matrix()[:3, :3]).dot(nrm)
        kw["normal"] = nrm
    if req.depth < 1e9:
        kw["depth"] = float(req.depth)
    return kw


def add_links(d: Deformable, links) -> int:
    """Join element pairs with new links carrying the body's material limits; returns how many."""

    soft = d.body
    if soft.dynamic:
        raise ValueError(f"adding links needs a ChainMail body; this one runs {soft.model_used}")
    added = soft.model_body.add_links(links)
    if added:
        soft.version += 1
    return added


# -- systems -------------------------------------------------------------------------------------


def reset(d: Deformable) -> int:
    """Rest shape, all links alive, nothing held; returns how many elements were displaced."""
    soft = d.body
    moved = int(np.count_nonzero(np.any(soft.positions != soft.rest, axis=1)))
    if soft.dynamic:
        use_model(d, soft.model_used)  # a fresh body: rest shape, every constraint back
        return moved
    soft.model_body.reset()
    soft.held = soft.model_body.held
    soft.changed()
    return moved


def deformation_system(app: App) -> None:
    """Serve every request in the order it was emitted (a release after a grab undoes that grab's hold)."""
    st: DeformationState = app.resource(DeformationState)
    if not st.announced:
        st.announced = True
        for line in model_lines(auto_only=True):
            _say(app, line, 10.0)
    counts: dict[int, list] = {}
    drag_type = type(None) if st.drag_type is None else st.drag_type
    for ev in st.requests.read():
        if isinstance(ev, drag_type):
            for req in _drag_requests(st, ev):
                _serve(app, st, req, counts)
        elif isinstance(ev, REQUESTS):
            _serve(app, st, ev, counts)
        elif isinstance(ev, Widget) and ev.name == "model":
            switch_models(app, st, str(ev.value))
    for ent, d in esper.get_component(Deformable):
        if d.body.dynamic:
            try:
                counts.setdefault(ent, [0, 0, 0])[0] += step_body(d, app.time.dt)
            except ValueError as e:
                st.errors.append(f"{d.body.model_used} body {ent}: {e}")
    for ent, (m, c, a) in counts.items():
        if m or c or a:
            app.events.emit(Deformed(ent, m, c, a))
    del st.errors[:-20]  # keep the last few for summaries and tests


REQUESTS = (GrabRequest, ReleaseRequest, CutRequest, AddLinksRequest, ResetRequest)

#: the order the model switch (Widget "model" with value "next", key m in the packs) walks: volumes reach
#: the hybrid body, sheets SurfaceChainMail (each only runs on its own kind of mesh)
SWITCH_ORDER = ("chainmail", "xpbd", "projective", "hybrid")
SWITCH_ORDER_SURFACE = ("surface", "chainmail", "xpbd", "projective")


def model_lines(auto_only: bool = False) -> list[str]:
    """One line per soft body naming the model it runs and why (for `auto`: the choice and its reason)."""
    out = []
    for ent, d in esper.get_component(Deformable):
        soft = d.body
        if auto_only and not soft.model_reason.startswith("auto") and "; " not in soft.model_reason:
            continue
        name = esper.component_for_entity(ent, Name).value if esper.has_component(ent, Name) else f"body {ent}"
        why = soft.model_reason if soft.model_reason.startswith("auto") else soft.model_reason.partition("; ")[2]
        out.append(f"{name}: {soft.model_used}" + (f" - {why}" if why else ""))
    return out


def _say(app: App, text: str, seconds: float) -> None:
    hud = app.get_resource(HudState)
    if hud is not None:
        hud.message(text, seconds)


def switch_models(app: App, st: DeformationState, value: str) -> None:
    """Put every deformable body under another model, from rest: `value` names one or is "next"."""
    for _ent, d in esper.get_component(Deformable):
        mesh = d.body.mesh
        volume = mesh.tets is not None and len(mesh.tets) > 0
        choices = list(SWITCH_ORDER if volume else SWITCH_ORDER_SURFACE)
        if value in choices:
            model = value
        elif value in SWITCH_ORDER + SWITCH_ORDER_SURFACE:
            continue  # a model for the other kind of mesh: this body keeps its own
        else:  # the button (True) or "next": the next model in turn
            cur = d.body.model_used if d.body.model_used in choices else choices[-1]
            model = choices[(choices.index(cur) + 1) % len(choices)]
        try:
            use_model(d, model)
        except UserError as e:
            st.errors.append(f"model switch: {e}")
    models = sorted({d.body.model_used for _e, d in esper.get_component(Deformable)})
    if models:
        _say(app, f"Tissue model: {', '.join(models)} (m switches)", 3.0)


def _serve(app: App, st: DeformationState, req, counts: dict) -> None:
    ent = _entity(app, req.entity)
    d = esper.try_component(ent, Deformable) if ent is not None and esper.entity_exists(ent) else None
    if ent is None or d is None:
        st.errors.append(f"{type(req).__name__}: no deformable entity {req.entity!r}")
        return
    c = counts.setdefault(ent, [0, 0, 0])
    try:
        if isinstance(req, GrabRequest):
            pts = to_local(ent, as_points(req.targets, "GrabRequest.targets"), req.frame)
            changed = grab(d, req.ids, pts, hold=req.hold)
            c[0] += len(changed)
        elif isinstance(req, ReleaseRequest):
            release(d, req.ids)
        elif isinstance(req, CutRequest):
            c[1] += cut(d, ent, req)
        elif isinstance(req, ResetRequest):
            c[0] += reset(d)
        else:
            c[2] += add_links(d, req.links)
    except ValueError as e:
        st.errors.append(f"{type(req).__name__} on {req.entity!r}: {e}")


def _drag_requests(st: DeformationState, ev) -> list:
    """A mouse drag on a deformable body (view_events.Dragged) as grab and release requests.

    The element nearest the grab point follows the cursor: its target is its position at the start plus
    the cursor's displacement in the plane the view system drags in.
    """
    ent = ev.entity
    d = esper.try_component(ent, Deformable) if esper.entity_exists(ent) else None
    if d is None or not d.drag:
        return []
    if ev.phase == "start":
        local = to_local(ent, np.asarray([ev.grab_point], dtype=np.float64), "world")[0]
        pos = d.body.positions
        v = int(np.argmin(np.sum((pos - local) ** 2, axis=1)))
        st.dragging[ent] = (
            v,
            _to_world(ent, pos[v][None, :].astype(np.float64))[0],
            np.asarray(ev.grab_point, dtype=np.float64),
        )
        return []
    if ent not in st.dragging:
        return []
    v, start, grab_point = st.dragging[ent]
    target = start + (np.asarray(ev.point, dtype=np.float64) - grab_point)
    out: list[GrabRequest | ReleaseRequest] = [GrabRequest(ent, np.array([v]), target[None, :], frame="world")]
    if ev.phase == "end":
        out.append(ReleaseRequest(ent, np.array([v])))
        del st.dragging[ent]
    return out


def _path_target(p: Pull, start: np.ndarray) -> tuple[np.ndarray, bool]:
    pts = np.vstack([start[None, :], p.waypoints])
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    left = p.travelled
    for i, length in enumerate(seg):
        if left <= length:
            t = left / length if length > 0 else 1.0
            return pts[i] + (pts[i + 1] - pts[i]) * t, False
        left -= length
    return pts[-1].copy(), True


def pull_system(app: App) -> None:
    """Turns `pull` components into GrabRequests along their paths (simulated time only)."""
    st: DeformationState = app.resource(DeformationState)
    pressed = {w.name for w in st.widgets.read()}
    for ent, (p, d) in esper.get_components(Pull, Deformable):
        if p.done:
            continue
        if not p.started:
            if (p.widget and p.widget in pressed) or (not p.widget and app.time.sim_time + 1e-12 >= p.start):
                p.started = True
                if p.resolved < 0:
                    p.resolved = _pull_element(ent, p, d)
                if p.frame == "world":
                    p.waypoints = to_local(ent, p.waypoints, "world")
                p.start_at = d.body.positions[p.resolved].astype(np.float64)
            else:
                continue
        p.travelled += p.speed * app.time.dt
        target, finished = _path_target(p, p.start_at)
        app.events.emit(GrabRequest(ent, np.array([p.resolved]), target[None, :], frame="local", hold=True))
        if finished:
            p.done = True
            if not p.hold:
                app.events.emit(ReleaseRequest(ent, np.array([p.resolved])))


def _pull_element(ent: int, p: Pull, d: Deformable) -> int:
    n = d.body.n
    if p.element >= 0:
        if p.element >= n:
            name = esper.try_component(ent, Name)
            raise UserError(
                f"entities.{name.value if name else ent}.pull.element: {p.element} is not an element id (0..{n - 1})"
            )
        return int(p.element)
    at = np.asarray(p.at, dtype=np.float64)[None, :]
    if p.frame == "world":
        at = to_local(ent, at, "world")
    return int(np.argmin(np.sum((d.body.rest - at) ** 2, axis=1)))


def _default_deformables(app: App) -> None:
    """Entities with simulation.kind surface/volume and a mesh but no deformable table get one."""

    pres = app.get_resource(PackResource)
    if pres is None:
        return
    for ent, (sim, mref) in esper.get_components(Simulation, MeshRef):
        if sim.kind in ("surface", "volume") and not esper.has_component(ent, Deformable):
            d = Deformable(source=sim.kind)
            setup_deformable(
                d,
                pres.pack.mesh(mref.mesh),
                pres.pack.section("materials"),
                mref.material,
                f"entities.{esper.component_for_entity(ent, Name).value}.simulation",
            )
            esper.add_component(ent, d)


def plugin(app: App) -> None:
    with app.active():
        _default_deformables(app)
        needed = bool(esper.get_component(Deformable))
        pulls = bool(esper.get_component(Pull))
        for ent, (p, d) in esper.get_components(Pull, Deformable):
            p.resolved = _pull_element(ent, p, d)
    if not needed:
        return
    ev = app.events
    st = DeformationState(ev.reader(None), ev.reader(Widget))
    st.drag_type = Dragged
    app.insert_resource(st)
    if pulls:
        app.add_system("simulation", pull_system, order=ORDER_PULL, name="pull")
    app.add_system("simulation", deformation_system, order=ORDER_DEFORMATION, name="deformation")

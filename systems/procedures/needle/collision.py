"""Needle collision: a swept segment test against the pack's targets and obstacles (thesis 3.3.6).

Stage: simulation (ORDER_COLLISION), after the needle kinematics. Reads: Needle, NeedleState,
NeedleScene (the pack's [roles]: which entities are targets and obstacles, and what an obstacle does
on contact), NeedleObstacles (built once from those entities' meshes). Writes: NeedleState (tip
stopped at the first surface met, bounce back, contact counts per role, Transform via the needle
system's pose helper, and the touches that decide whether the next contact counts); emits NeedleHit.

The thesis detected contacts by letting the needle-tip viewpoint collide with the scene. Here the
same question - what does the tip meet first? - is answered exactly: whenever the tip moves forward,
the segment from the entry point to the new tip (the shaft, which contains the sweep from the old tip)
is intersected with every target's and blocking obstacle's triangles and the nearest hit wins.
Because the whole sweep is tested, an insertion of any length in one step cannot pass through bone.
Obstacles that only warn are tested along the sweep from the old tip, so each is met once on the way
in. Skin and tissue are not obstacles. On contact (the role's `on_contact`): the side's target stops
the needle for good; bounce springs it back by the needle's `bounce`; stop leaves it where it touched.

Contacts are counted per role as a clinician counts them (`new_contact`): pushing on at the same
place - key taps against bone, each answered by the spring-back - is one contact; the next one counts
after the needle was withdrawn `recontact_withdraw` (2 mm by default) beyond where the spring-back
left it, turned by `recontact_angle` (2 degrees), or meets the role `recontact_distance` (2 mm) from the
last counted point. Every touch is still signalled (NeedleHit, with `counted` saying which kind).

The segment query is the engine's (chainsim.systems.engine.segment_tree).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import MeshRef, Transform, to_world
from chainsim.components.resources import EntityIndex, PackResource
from chainsim.components.stages import ORDER_COLLISION
from chainsim.systems.engine.segment_tree import SegmentTree
from chainsim.systems.procedures.needle.components import Needle, NeedleState, Touch
from chainsim.systems.procedures.needle.kinematics import apply_pose, sync_widgets
from chainsim.systems.procedures.needle.manifest import NeedleScene


@dataclass(slots=True)
class NeedleObstacles:
    """The obstacle entities' meshes prepared for segment queries (resource, built once)."""

    names: list[str] = field(default_factory=list)
    trees: list[SegmentTree] = field(default_factory=list)

    def first_hit(self, p0, p1, only=None, skip=()) -> tuple[str, float, int]:
        """(object name, t, triangle) of the nearest hit over the obstacles (those in `only` if given, none
        in `skip`), or ("", inf, -1)."""
        best = ("", np.inf, -1)
        for name, tree in zip(self.names, self.trees):
            if (only is not None and name not in only) or name in skip:
                continue
            t, i = tree.first_hit(p0, p1)
            if t < best[1]:
                best = (name, t, i)
        return best


def build_obstacles(app: App, names) -> NeedleObstacles:
    """Meshes of the named entities (targets and obstacles), through their Transform (static scenery)."""

    pack = app.resource(PackResource).pack
    index: EntityIndex = app.resource(EntityIndex)
    obs = NeedleObstacles()
    with app.active():
        for name in names:
            ent = index.get(name)
            if ent is None:
                continue
            ref = esper.try_component(ent, MeshRef)
            if ref is None:
                continue
            mesh = pack.mesh(ref.mesh)
            world = to_world(esper.try_component(ent, Transform), mesh.vertices)
            obs.names.append(name)
            obs.trees.append(SegmentTree.build(world, mesh.triangles))
    return obs


# -- the system ---------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class NeedleHit:
    """The needle tip met `object` (playing `role`) at `point` (world mm); `distance_to_target_mm` is the
    distance from the tip to the centre of the entry side's target (the Dist of E = Dist - R, 6.1.5).
    `counted`: a new contact; False when the needle was pushed on at the same place (`new_contact`)."""

    object: str
    point: tuple[float, float, float]
    distance_to_target_mm: float
    depth_mm: float
    role: str = ""
    counted: bool = True


def _xyz(p) -> tuple[float, float, float]:
    """A point as the three plain floats NeedleHit carries."""
    return (float(p[0]), float(p[1]), float(p[2]))


def new_contact(needle: Needle, st: NeedleState, role: str, point, direction) -> bool:
    """Whether touching `role` at `point` is a new contact, as a clinician counts them: the first one;
    or, since the last, the needle withdrawn `recontact_withdraw` past where that one left it (the
    spring-back is the simulator's answer, not the trainee's withdrawal), turned by `recontact_angle`,
    or touching `recontact_distance` from the last counted point. Pushing on in place is one contact."""
    last = st.touches.get(role)
    if last is None:
        return True
    withdrawn = last.shallowest <= last.rest - needle.recontact_withdraw + 1e-9
    cos = float(np.clip(np.dot(direction, last.direction), -1.0, 1.0))
    turned = np.degrees(np.arccos(cos)) >= needle.recontact_angle - 1e-9
    moved = float(np.linalg.norm(np.asarray(point) - last.point)) >= needle.recontact_distance - 1e-9
    return bool(withdrawn or turned or moved)


def touch(needle: Needle, st: NeedleState, role: str, point, direction, rest: float) -> bool:
    """Book a touch of `role`: counted if it is a new contact (`new_contact`); either way the withdrawal
    is measured from `rest`, the depth this touch leaves the needle at. Returns whether it counted."""
    counted = new_contact(needle, st, role, point, direction)
    last = st.touches.get(role)
    if counted or last is None:
        st.contacts[role] = st.contacts.get(role, 0) + 1
        st.touches[role] = Touch(np.asarray(point, float).copy(), np.asarray(direction, float).copy(), rest, rest)
    else:
        last.rest = last.shallowest = float(rest)
    return counted


def _warn_hit(app: App, scene: NeedleScene, needle: Needle, st: NeedleState, warn: set, target, name: str, t: float):
    """Obstacles that only warn, met along the sweep from the old tip before the first blocking hit."""
    d = st.direction()
    p1 = st.entry + st.depth * d
    p0 = st.entry + st.prev_depth * d
    side = scene.side_of(st.entry)
    wname, wt, _ = app.resource(NeedleObstacles).first_hit(p0, p1, only=warn - set(target.entities))
    if not wname or (name and st.prev_depth + wt * (st.depth - st.prev_depth) >= t * st.depth):
        return
    wdepth = st.prev_depth + wt * (st.depth - st.prev_depth)
    point = st.entry + wdepth * d
    rname = _role_name(scene, wname, side)
    counted = touch(needle, st, rname, point, d, float(wdepth))
    dist = float(np.linalg.norm(point - target.centre))
    app.events.emit(NeedleHit(wname, _xyz(point), dist, float(wdepth), rname, counted))


def collision_system(app: App) -> None:

    obs: NeedleObstacles = app.resource(NeedleObstacles)
    scene: NeedleScene = app.resource(NeedleScene)
    warn = {e for r in scene.roles.values() if r.kind == "obstacle" and r.on_contact == "warn" for e in r.entities}
    for ent, (needle, st) in esper.get_components(Needle, NeedleState):
        for last in st.touches.values():  # how far the needle has been withdrawn since each role's contact
            last.shallowest = min(last.shallowest, st.depth)
        if not st.placed or st.depth <= st.prev_depth + 1e-12:
            continue
        side = scene.side_of(st.entry)
        target = scene.target(side)
        d = st.direction()
        p1 = st.entry + st.depth * d
        # what warns is met on the way in only; the side's target is never a mere warning
        name, t, _tri = obs.first_hit(st.entry, p1, skip=warn - set(target.entities))
        if warn:
            _warn_hit(app, scene, needle, st, warn, target, name, t)
        if not name:
            continue
        hit_depth = t * st.depth
        point = st.entry + hit_depth * d
        dist = float(np.linalg.norm(point - target.centre))
        stop = max(hit_depth - needle.contact_epsilon, 0.0)
        st.path_length += abs(stop - st.prev_depth) - abs(st.depth - st.prev_depth)
        st.depth = stop
        st.contact = name
        st.contact_point = point.copy()
        role = scene.role_of(name, side)
        rname = role.name if role is not None else ""
        if role is not None and role.kind == "target":
            st.target_depth = stop
            st.done = True
        elif role is not None and role.on_contact == "stop":
            st.target_depth = stop
        else:
            # bounce: spring back (thesis 3.3.6)
            st.target_depth = max(stop - needle.bounce, 0.0)
        counted = touch(needle, st, rname, point, d, st.target_depth)
        st.prev_depth = stop
        apply_pose(app, ent, needle, st)
        sync_widgets(app, st, needle)  # the depth slider shows where the needle is going after the contact
        app.events.emit(NeedleHit(name, _xyz(point), dist, float(hit_depth), rname, counted))


def _role_name(scene: NeedleScene, entity: str, side: str) -> str:
    role = scene.role_of(entity, side)
    return role.name if role is not None else ""


def plugin(app: App) -> None:
    """Install the collision test over the NeedleScene resource's targets and obstacles (put there first)."""
    app.insert_resource(build_obstacles(app, app.resource(NeedleScene).obstacles()))

    app.add_system("simulation", collision_system, order=ORDER_COLLISION, name="needle_collision")

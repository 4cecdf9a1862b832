"""Needle collision: a swept segment test against the skull, mandible and foramina (thesis 3.3.6).

Stage: simulation (ORDER_COLLISION), after the needle kinematics. Reads: Needle, NeedleState,
PrpObstacles (built once from the meshes of the obstacle entities). Writes: NeedleState (tip stopped
at the first surface met, bounce back from bone, contact counts, Transform via the needle system's
pose helper); emits NeedleHit.

The thesis detected contacts by letting the needle-tip viewpoint collide with the scene. Here the
same question - what does the tip meet first? - is answered exactly: whenever the tip moves forward,
the segment from the entry point to the new tip (the shaft, which contains the sweep from the old tip)
is intersected with every obstacle's triangles and the nearest hit wins. Because the whole sweep is
tested, an insertion of any length in one step cannot pass through bone. Skin is not an obstacle.

The segment query is the engine's (chainsim.engine.segment_tree).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import esper
import numpy as np

from chainsim.components.core import MeshRef, Transform
from chainsim.components.needle import Needle, NeedleState
from chainsim.components.procedure import PrpAnatomy
from chainsim.components.resources import EntityIndex, PackResource
from chainsim.engine.segment_tree import SegmentTree
from chainsim.systems.needle import apply_pose, sync_widgets
from chainsim.systems.stages import ORDER_COLLISION


@dataclass(slots=True)
class PrpObstacles:
    """The obstacle entities' meshes prepared for segment queries (resource, built once)."""

    names: list[str] = field(default_factory=list)
    trees: list[SegmentTree] = field(default_factory=list)

    def first_hit(self, p0, p1) -> tuple[str, float, int]:
        """(object name, t, triangle) of the nearest hit over all obstacles, or ("", inf, -1)."""
        best = ("", np.inf, -1)
        for name, tree in zip(self.names, self.trees):
            t, i = tree.first_hit(p0, p1)
            if t < best[1]:
                best = (name, t, i)
        return best


OBSTACLES = ("skull", "mandible", "foramen_ovale_left", "foramen_ovale_right")


def build_obstacles(app) -> PrpObstacles:
    """Meshes of the obstacle entities, through their Transform (static scenery)."""

    pack = app.resource(PackResource).pack
    index: EntityIndex = app.resource(EntityIndex)
    obs = PrpObstacles()
    with app.active():
        for name in OBSTACLES:
            ent = index.get(name)
            if ent is None:
                continue
            ref = esper.try_component(ent, MeshRef)
            if ref is None:
                continue
            mesh = pack.mesh(ref.mesh)
            tr = esper.try_component(ent, Transform)
            m = tr.matrix() if tr is not None else np.eye(4)
            world = mesh.vertices @ m[:3, :3].T + m[:3, 3]
            obs.names.append(name)
            obs.trees.append(SegmentTree.build(world, mesh.triangles))
    return obs


# -- the system ---------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class NeedleHit:
    """The needle tip met `object` at `point` (world mm); `distance_to_target_mm` is the distance from
    the tip to the centre of the foramen ovale on the entry side (the Dist of E = Dist - R, 6.1.5)."""

    object: str
    point: tuple[float, float, float]
    distance_to_target_mm: float
    depth_mm: float


def collision_system(app) -> None:

    obs: PrpObstacles = app.resource(PrpObstacles)
    anat: PrpAnatomy = app.resource(PrpAnatomy)
    for ent, (needle, st) in esper.get_components(Needle, NeedleState):
        if not st.placed or st.depth <= st.prev_depth + 1e-12:
            continue
        d = st.direction()
        p1 = st.entry + st.depth * d
        name, t, _tri = obs.first_hit(st.entry, p1)
        if not name:
            continue
        hit_depth = t * st.depth
        point = st.entry + hit_depth * d
        side = anat.side_of(st.entry)
        fo = anat.sides[side]
        dist = float(np.linalg.norm(point - fo.foramen_centre))
        stop = max(hit_depth - needle.contact_epsilon, 0.0)
        st.path_length += abs(stop - st.prev_depth) - abs(st.depth - st.prev_depth)
        st.depth = stop
        st.contact = name
        st.contact_point = point.copy()
        if name == f"foramen_ovale_{side}":
            st.target_depth = stop
            st.done = True
        else:
            # bone (or the other side's opening, which is in bone): spring back (thesis 3.3.6)
            st.skull_contacts += 1
            st.target_depth = max(stop - needle.bounce, 0.0)
        st.prev_depth = stop
        apply_pose(app, ent, needle, st)
        sync_widgets(app, st)  # the depth slider shows where the needle is going after the contact
        app.events.emit(NeedleHit(name, tuple(float(c) for c in point), dist, float(hit_depth)))


def plugin(app) -> None:
    app.insert_resource(build_obstacles(app))

    app.add_system("simulation", collision_system, order=ORDER_COLLISION, name="needle_collision")

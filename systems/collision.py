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

The kernel (`segment_first_hit`) is a pure numba function over a two-level box hierarchy: triangles
sorted along a Morton curve, grouped in chunks of CHUNK with bounding boxes, chunks grouped again.
Each level is culled with a slab test clipped to the best hit found so far.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import esper
import numpy as np
from numba import njit

from chainsim.components.core import MeshRef, Transform
from chainsim.components.needle import Needle, NeedleState
from chainsim.components.procedure import PrpAnatomy
from chainsim.components.resources import EntityIndex, PackResource
from chainsim.systems.needle import _sync_widgets, apply_pose
from chainsim.systems.stages import ORDER_COLLISION

CHUNK = 16
GROUP = 16
BARY_EPS = 1e-9  # inclusive barycentric tolerance: a segment through a shared edge hits one side
BOX_PAD = 1e-6  # mm


# -- kernel -----------------------------------------------------------------------------------------


@njit(cache=True)
def _slab(p0, d, lo, hi, tmax):
    """Whether the segment p0 + t d, t in [0, tmax], meets the box [lo, hi]."""
    t0 = 0.0
    t1 = tmax
    for a in range(3):
        if abs(d[a]) < 1e-300:
            if p0[a] < lo[a] or p0[a] > hi[a]:
                return False
        else:
            inv = 1.0 / d[a]
            ta = (lo[a] - p0[a]) * inv
            tb = (hi[a] - p0[a]) * inv
            if ta > tb:
                ta, tb = tb, ta
            if ta > t0:
                t0 = ta
            if tb < t1:
                t1 = tb
            if t0 > t1:
                return False
    return True


@njit(cache=True)
def _tri_t(p0, d, v0, e1, e2):
    """Moller-Trumbore: the segment parameter of the hit (two-sided), or -1 when missed."""
    px = d[1] * e2[2] - d[2] * e2[1]
    py = d[2] * e2[0] - d[0] * e2[2]
    pz = d[0] * e2[1] - d[1] * e2[0]
    det = e1[0] * px + e1[1] * py + e1[2] * pz
    if abs(det) < 1e-300:
        return -1.0
    inv = 1.0 / det
    sx = p0[0] - v0[0]
    sy = p0[1] - v0[1]
    sz = p0[2] - v0[2]
    u = (sx * px + sy * py + sz * pz) * inv
    if u < -BARY_EPS or u > 1.0 + BARY_EPS:
        return -1.0
    qx = sy * e1[2] - sz * e1[1]
    qy = sz * e1[0] - sx * e1[2]
    qz = sx * e1[1] - sy * e1[0]
    v = (d[0] * qx + d[1] * qy + d[2] * qz) * inv
    if v < -BARY_EPS or u + v > 1.0 + BARY_EPS:
        return -1.0
    return (e2[0] * qx + e2[1] * qy + e2[2] * qz) * inv


@njit(cache=True)
def segment_first_hit(p0, p1, v0, e1, e2, chunk_lo, chunk_hi, group_lo, group_hi, n_tri):
    """(t, i): the smallest t in [0, 1] where p0 + t (p1 - p0) meets triangle i (in sorted order),
    or (inf, -1). Triangles are v0 + a e1 + b e2; chunk c holds triangles [c*CHUNK, (c+1)*CHUNK),
    group g holds chunks [g*GROUP, (g+1)*GROUP)."""
    d = p1 - p0
    best = np.inf
    best_i = -1
    n_chunk = chunk_lo.shape[0]
    for g in range(group_lo.shape[0]):
        lim = best if best < 1.0 else 1.0
        if not _slab(p0, d, group_lo[g], group_hi[g], lim):
            continue
        c_end = min((g + 1) * GROUP, n_chunk)
        for c in range(g * GROUP, c_end):
            lim = best if best < 1.0 else 1.0
            if not _slab(p0, d, chunk_lo[c], chunk_hi[c], lim):
                continue
            t_end = min((c + 1) * CHUNK, n_tri)
            for i in range(c * CHUNK, t_end):
                t = _tri_t(p0, d, v0[i], e1[i], e2[i])
                if t >= 0.0 and t <= 1.0 and t < best:
                    best = t
                    best_i = i
    return best, best_i


# -- precomputed meshes -------------------------------------------------------------------------------


def _morton(c: np.ndarray) -> np.ndarray:
    lo, hi = c.min(0), c.max(0)
    q = ((c - lo) / np.maximum(hi - lo, 1e-9) * 1023).astype(np.uint64)
    code = np.zeros(len(c), dtype=np.uint64)
    for bit in range(10):
        for a in range(3):
            code |= ((q[:, a] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + a)
    return code


@dataclass(slots=True)
class SegmentTree:
    """One mesh prepared for `segment_first_hit` (world millimetres)."""

    v0: np.ndarray
    e1: np.ndarray
    e2: np.ndarray
    chunk_lo: np.ndarray
    chunk_hi: np.ndarray
    group_lo: np.ndarray
    group_hi: np.ndarray
    order: np.ndarray  # sorted index -> original triangle index

    @classmethod
    def build(cls, vertices: np.ndarray, triangles: np.ndarray) -> SegmentTree:
        vertices = np.asarray(vertices, dtype=np.float64)
        triangles = np.asarray(triangles, dtype=np.int64).reshape(-1, 3)
        corners = vertices[triangles]  # (F, 3, 3)
        order = np.argsort(_morton(corners.mean(axis=1)), kind="stable") if len(triangles) else np.zeros(0, np.int64)
        corners = corners[order]
        v0 = np.ascontiguousarray(corners[:, 0])
        e1 = np.ascontiguousarray(corners[:, 1] - corners[:, 0])
        e2 = np.ascontiguousarray(corners[:, 2] - corners[:, 0])
        n = len(corners)
        n_chunk = (n + CHUNK - 1) // CHUNK
        tlo, thi = corners.min(axis=1), corners.max(axis=1)
        chunk_lo = np.empty((n_chunk, 3))
        chunk_hi = np.empty((n_chunk, 3))
        for c in range(n_chunk):
            chunk_lo[c] = tlo[c * CHUNK : (c + 1) * CHUNK].min(0) - BOX_PAD
            chunk_hi[c] = thi[c * CHUNK : (c + 1) * CHUNK].max(0) + BOX_PAD
        n_group = (n_chunk + GROUP - 1) // GROUP
        group_lo = np.empty((n_group, 3))
        group_hi = np.empty((n_group, 3))
        for g in range(n_group):
            group_lo[g] = chunk_lo[g * GROUP : (g + 1) * GROUP].min(0)
            group_hi[g] = chunk_hi[g * GROUP : (g + 1) * GROUP].max(0)
        return cls(v0, e1, e2, chunk_lo, chunk_hi, group_lo, group_hi, order.astype(np.int64))

    def first_hit(self, p0, p1) -> tuple[float, int]:
        """(t in [0, 1], original triangle index) of the first hit along p0 -> p1, or (inf, -1)."""
        if len(self.v0) == 0:
            return np.inf, -1
        t, i = segment_first_hit(
            np.asarray(p0, np.float64),
            np.asarray(p1, np.float64),
            self.v0,
            self.e1,
            self.e2,
            self.chunk_lo,
            self.chunk_hi,
            self.group_lo,
            self.group_hi,
            len(self.v0),
        )
        return (float(t), int(self.order[i])) if i >= 0 else (np.inf, -1)


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
        _sync_widgets(app, st)  # the depth slider shows where the needle is going after the contact
        app.events.emit(NeedleHit(name, tuple(float(c) for c in point), dist, float(hit_depth)))


def plugin(app) -> None:
    app.insert_resource(build_obstacles(app))

    app.add_system("simulation", collision_system, order=ORDER_COLLISION, name="needle_collision")

"""Picking without GL: ray -> (entity, triangle, point) on the current (possibly deformed) meshes, and a
world point -> nearest surface point (thesis 3.3.4: a point is marked by clicking on a surface).

The ray test (chainsim.systems.engine.raycast) is a vectorised, two-sided Moller-Trumbore over every triangle of each
candidate mesh
(after a bounding-sphere cull), on the vertex positions the renderer draws: its soft body's positions
(Deformable.body) when the entity has one, else the pack mesh, mapped through the entity's Transform.
Triangles that lost an edge to a cut (a dead ChainMail link, thesis 4.5.2) are neither drawn nor picked.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import MeshRef, Name, Transform, to_world
from chainsim.components.resources import PackResource
from chainsim.systems.engine.bodies.soft import SoftBody
from chainsim.systems.engine.raycast import closest_on_mesh, ray_mesh, triangle_links
from chainsim.systems.tissue.deformable import Deformable


@dataclass(slots=True)
class Hit:
    entity: int
    name: str
    triangle: int
    point: np.ndarray  # world mm
    distance: float  # along the ray from its origin


@dataclass(slots=True)
class _Surface:
    tri_links: np.ndarray  # per triangle, its three links (-1: none)
    graph_id: int = 0
    dead: int = -1
    live: np.ndarray | None = None  # indices of triangles still drawn


@dataclass(slots=True)
class SurfaceCache:
    """Per-entity triangle lists with cut triangles removed (resource shared by renderer and picking)."""

    items: dict[int, _Surface] = field(default_factory=dict)

    def live_triangles(self, entity: int, triangles: np.ndarray, body: SoftBody | None) -> np.ndarray:
        """Indices (into `triangles`) of the triangles whose edges are all alive (`body`: the entity's
        soft body, None for a mesh that does not deform)."""
        graph = body.graph if body is not None else None
        alive = body.alive if body is not None else None
        if graph is None or alive is None or len(alive) == 0:
            return np.arange(len(triangles))
        s = self.items.get(entity)
        if s is None or s.graph_id != id(graph):
            s = _Surface(graph_id=id(graph), tri_links=triangle_links(triangles, np.asarray(graph.links)))
            self.items[entity] = s
        dead = int(len(alive) - np.count_nonzero(alive))
        if dead != s.dead or s.live is None:
            tl = s.tri_links
            ok = np.ones(len(triangles), bool)
            if dead:
                ok = np.all((tl < 0) | alive[np.maximum(tl, 0)], axis=1)
            s.live = np.flatnonzero(ok)
            s.dead = dead
        return s.live


def surface_cache(app: App) -> SurfaceCache:
    c = app.get_resource(SurfaceCache)
    if c is None:
        c = app.insert_resource(SurfaceCache())
    return c


def entity_surface(app: App, ent: int, mesh_ref=None, transform=None):
    """(world vertices, triangles, triangle ids) of an entity's current surface, or None."""

    mesh_ref = mesh_ref or esper.try_component(ent, MeshRef)
    if mesh_ref is None:
        return None
    mesh = app.resource(PackResource).pack.mesh(mesh_ref.mesh)
    if len(mesh.triangles) == 0:
        return None
    body = _soft_body(ent)
    local = np.asarray(body.positions, float) if body is not None and body.n else mesh.vertices
    transform = transform or esper.try_component(ent, Transform)
    tri_ids = surface_cache(app).live_triangles(ent, mesh.triangles, body)
    return to_world(transform, local), mesh.triangles, tri_ids


def _soft_body(ent: int) -> SoftBody | None:
    d = esper.try_component(ent, Deformable)
    return d.body if d is not None else None


def pick(app: App, origin, direction) -> Hit | None:
    """Nearest hit over visible, pickable mesh entities (call inside `app.active()` or a system)."""

    d = np.asarray(direction, float)
    o = np.asarray(origin, float)
    best: Hit | None = None
    for ent, ref in esper.get_component(MeshRef):
        if not (ref.visible and ref.pickable):
            continue
        surf = entity_surface(app, ent, ref, esper.try_component(ent, Transform))
        if surf is None:
            continue
        verts, tris, ids = surf
        centre = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
        radius = 0.5 * float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)))
        w = centre - o
        along = float(w @ d)
        if float(w @ w) - along * along > radius * radius * (1 + 1e-9) + 1e-9:
            continue  # the ray misses the bounding sphere
        if along < -radius:
            continue
        if best is not None and along - radius > best.distance:
            continue
        found = ray_mesh(o, d, verts, tris[ids])
        if found is None:
            continue
        k, t = found
        if best is None or t < best.distance:
            name = esper.try_component(ent, Name)
            best = Hit(ent, name.value if name else str(ent), int(ids[k]), o + t * d, t)
    return best


def snap(app: App, entity: int, point) -> Hit | None:
    """The surface point of `entity` nearest to a world point (scripted PickPoint events)."""

    surf = entity_surface(app, entity)
    if surf is None:
        return None
    verts, tris, ids = surf
    k, p = closest_on_mesh(verts, tris[ids], point)
    name = esper.try_component(entity, Name)
    return Hit(
        entity, name.value if name else str(entity), int(ids[k]), p, float(np.linalg.norm(p - np.asarray(point, float)))
    )

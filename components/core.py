"""Core components every pack can use: name, transform, mesh, material, scripted motion, simulation kind.

Vectors are float64 numpy arrays in millimetres; rotations are unit quaternions [w, x, y, z].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from chainsim.components.registry import component, prop
from chainsim.systems.engine import quaternion


@dataclass(slots=True)
class Name:
    """The entity's manifest name (set by the loader, not a manifest table)."""

    value: str


@component("transform", help="Where the entity is: position, rotation and uniform scale.")
@dataclass(slots=True)
class Transform:
    position: np.ndarray = prop("vec3", (0.0, 0.0, 0.0), units="mm", help="Position of the entity's origin.")
    rotation: np.ndarray = prop("quat", (1.0, 0.0, 0.0, 0.0), help="Orientation as a unit quaternion [w, x, y, z].")
    scale: float = prop("float", 1.0, help="Uniform scale.", min=1e-9)

    def matrix(self) -> np.ndarray:
        """4 x 4 model matrix (column vectors)."""
        r = quaternion.to_matrix(self.rotation)
        m = np.eye(4)
        m[:3, :3] = r * self.scale
        m[:3, 3] = self.position
        return m

    # every local <-> world conversion of points goes through these two, so that the mesh a body
    # simulates, the one drawn, picked and collided with, and the points scripts name agree to the bit
    def apply(self, points: ArrayLike) -> np.ndarray:
        """Local point(s), shape (3,) or (N, 3) -> world: scaled, rotated by the quaternion, moved by the
        position (float64)."""
        m = self.matrix()
        return np.asarray(points, dtype=np.float64) @ m[:3, :3].T + m[:3, 3]

    def inverse_apply(self, points: ArrayLike) -> np.ndarray:
        """World point(s), shape (3,) or (N, 3) -> local: the inverse of `apply`."""
        m = np.linalg.inv(self.matrix())
        return np.asarray(points, dtype=np.float64) @ m[:3, :3].T + m[:3, 3]


def to_world(tr: Transform | None, points: ArrayLike) -> np.ndarray:
    """`tr.apply(points)`; an entity without a transform sits at the origin, unrotated, unscaled."""
    return (tr if tr is not None else Transform()).apply(points)


@component("mesh", help="Draw (and pick, and collide with) a mesh from the pack's [meshes].")
@dataclass(slots=True)
class MeshRef:
    mesh: str = prop("mesh", help="Name of the mesh in [meshes].")
    material: str = prop("material", "", help="Name of the material in [materials] (default grey).")
    visible: bool = prop("bool", True, help="Drawn at start (toggles may change it).")
    pickable: bool = prop("bool", True, help="Clicks can land on it.")
    layer: str = prop("str", "", help="Visibility group a toggle widget can switch (e.g. 'skin', 'planes').")


@component("simulation", help="What the engine models for this entity; systems skip what no entity needs.")
@dataclass(slots=True)
class Simulation:
    kind: str = prop(
        "enum",
        "rigid",
        choices=("none", "rigid", "surface", "volume"),
        help="none: static scenery; rigid: moves as a whole; surface / volume: ChainMail on the mesh's surface "
        "links or tetrahedra.",
    )


@component("scripted_motion", help="Moves the entity along waypoints in simulated time (demos, benchmarks).")
@dataclass(slots=True)
class ScriptedMotion:
    waypoints: np.ndarray = prop(
        "float_list", (), units="mm", help="Flat list x0,y0,z0, x1,y1,z1, ... visited in order.", stride=3
    )
    speed: float = prop("float", 10.0, units="mm/s", help="Speed along the path.", min=0.0)
    loop: bool = prop("bool", True, help="Start over after the last waypoint.")
    spin: np.ndarray = prop("vec3", (0.0, 0.0, 0.0), units="deg/s", help="Constant rotation rate about x, y, z.")
    # runtime state
    segment: int = 0
    travelled: float = 0.0


@component("label", help="A text label drawn at the entity (HUD).")
@dataclass(slots=True)
class Label:
    text: str = prop("str", help="Text.")
    color: np.ndarray = prop("vec4", (1.0, 1.0, 1.0, 1.0), help="RGBA 0..1.")


@component("marker", help="A point marker (sphere) drawn at the entity's position.")
@dataclass(slots=True)
class Marker:
    radius: float = prop("float", 2.0, units="mm", help="Marker radius.", min=0.0)
    color: np.ndarray = prop("vec4", (1.0, 0.8, 0.1, 1.0), help="RGBA 0..1.")
    layer: str = prop("str", "", help="Visibility group.")
    visible: bool = prop("bool", True, help="Drawn at start.")


@dataclass(slots=True)
class PolyLine:
    """Runtime line strip to draw (needle paths, cut paths): points in world mm."""

    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    color: tuple = (1.0, 1.0, 0.2, 1.0)
    visible: bool = True
    layer: str = ""


@dataclass(slots=True)
class Wireframe:
    """Runtime only (not a manifest table): draw this entity's mesh as its links, e.g. to show stretch."""

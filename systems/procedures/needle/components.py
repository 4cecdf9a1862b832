"""The needle of a needle procedure: its manifest settings (`[entities.X.needle]`) and its runtime state.

Thesis 3.3.4-3.3.6. The needle entity's Transform origin is the TIP and its local +Z axis points
along the direction of insertion, so a camera attached to it (the local viewer) looks where the
needle goes. The pose is kept as an entry point, an orientation quaternion and an insertion depth:

    tip = entry + depth * rotate(q, +Z)

Orientation is changed only by concatenated quaternion rotations (chainsim.systems.engine.quaternion), never by
re-deriving angles, as in 3.3.5.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from chainsim.components.registry import component, prop
from chainsim.systems.engine.quaternion import rotate


@component(
    "needle",
    help="A needle driven by the needle procedure: placed at the entry landmark, rotated (horizontal, then "
    "vertical), then inserted along its axis.",
)
@dataclass(slots=True)
class Needle:
    length: float = prop("float", 100.0, units="mm", help="Shaft length drawn behind the tip.", min=1.0)
    shaft: str = prop(
        "entity",
        "",
        help="Entity that draws the shaft (moved with the needle; its mesh is a cylinder centred on its origin).",
    )
    insert_step: float = prop(
        "float", 2.0, units="mm", help="Depth change per insert/withdraw button press or key press.", min=0.0
    )
    rotate_step: float = prop("float", 1.0, units="deg", help="Rotation per arrow-key press.", min=0.0)
    max_depth: float = prop("float", 150.0, units="mm", help="Deepest insertion allowed.", min=0.0)
    max_pitch: float = prop(
        "float",
        80.0,
        units="deg",
        help="Largest vertical rotation either way (keeps the horizontal axis defined).",
        min=0.0,
        max=89.0,
    )
    bounce: float = prop(
        "float", 4.0, units="mm", help="How far the needle springs back after touching bone (thesis 3.3.6).", min=0.0
    )
    withdraw_speed: float = prop(
        "float",
        60.0,
        units="mm/s",
        help="Speed of backward motion (bounce and withdrawal); forward insertion is immediate and swept.",
        min=1e-3,
    )
    insert_speed: float = prop(
        "float",
        0.0,
        units="mm/s",
        help="Speed of forward insertion toward the requested depth (0: the depth is reached in one step). "
        "Soft tissue's friction grows with speed, so a pack with tissue sets a hand's speed.",
        min=0.0,
    )
    contact_epsilon: float = prop(
        "float", 0.2, units="mm", help="Gap left between the tip and the surface it touched.", min=0.0
    )
    max_yaw: float = prop(
        "float",
        0.0,
        units="deg",
        help="Largest horizontal turn either way from where the needle was placed (0: no limit).",
        min=0.0,
        max=360.0,
    )
    aim_at: np.ndarray = prop(
        "vec3",
        (0.0, 0.0, 0.0),
        units="mm",
        help="When placed, the needle points level (in the axial plane) at the vertical axis through this point.",
    )
    lock_on_insert: bool = prop(
        "bool", True, help="Rotation locks once the needle is inserted (thesis 3.3.4); false: it may turn while in."
    )
    unlock_at_skin: bool = prop(
        "bool",
        True,
        help="Withdrawn back to the skin, the rotation unlocks where it is (withdraw and redirect); false: "
        "only a Reset unlocks it.",
    )
    recontact_withdraw: float = prop(
        "float",
        2.0,
        units="mm",
        help="A contact with the same role counts again only after the needle was withdrawn this far past "
        "where the last contact left it (after its spring-back), turned by recontact_angle, or touched "
        "recontact_distance away; pushing on at the same place is the same contact.",
        min=0.0,
    )
    recontact_angle: float = prop(
        "float", 2.0, units="deg", help="A turn this large since the last contact makes the next one new.", min=0.0
    )
    recontact_distance: float = prop(
        "float",
        2.0,
        units="mm",
        help="A contact this far from the last counted one on the same role is a new contact.",
        min=0.0,
    )


@dataclass(slots=True)
class Touch:
    """The last contact with one role (NeedleState.touches): where the last counted one was and which way
    the needle pointed then, the depth the needle was left at after the latest one (its spring-back
    included) and the shallowest depth since, which says how far the trainee has withdrawn."""

    point: np.ndarray
    direction: np.ndarray
    rest: float
    shallowest: float


@dataclass(slots=True)
class NeedleState:
    """Runtime pose and history of the needle (not a manifest table)."""

    placed: bool = False  # at landmark 1 (before that the needle is parked where the pack put it)
    entry: np.ndarray = field(default_factory=lambda: np.zeros(3))
    q0: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))
    q: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))
    yaw: float = 0.0  # degrees turned about the vertical axis since placement
    pitch: float = 0.0  # degrees tilted about the needle's horizontal axis (positive: tip up)
    depth: float = 0.0  # mm along the axis from the entry point
    target_depth: float = 0.0  # where insertion commands want the tip
    prev_depth: float = 0.0  # depth at the start of the current step (the swept segment's start)
    locked: bool = False  # rotation locked once insertion began (thesis 3.3.4)
    done: bool = False  # tip is in the target: no further insertion
    contact: str = ""  # object the tip touched last ("" none)
    contact_point: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    contacts: dict[str, int] = field(default_factory=dict)  # per role name, this attempt (the counted ones)
    touches: dict[str, Touch] = field(default_factory=dict)  # per role name: what decides the next counts
    rotation_refused: int = 0  # turns asked for while the needle was in (not while it withdrew to the skin)
    held_turns: list = field(default_factory=list)  # (widget, value, increment) asked for on the way back
    path_length: float = 0.0  # mm travelled by the tip while inserted (forward and back)
    redirections: int = 0  # times the needle was withdrawn to the skin and turned again
    withdrawn: bool = False  # back at the skin after an insertion: the next turn is a redirection
    park_position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    park_rotation: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))

    def direction(self) -> np.ndarray:

        return rotate(self.q, np.array([0.0, 0.0, 1.0]))

    def tip(self) -> np.ndarray:
        return self.entry + self.depth * self.direction()

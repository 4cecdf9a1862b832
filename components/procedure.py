"""Rhizotomy procedure data: the trainee's progress, the landmarks and the named anatomy it is scored on.

Thesis 3.2.3 (the steps), 3.3.4 (three landmarks, the assessment tool) and 6.1.5 (the error
formulas). `ProcedureState` lives on a runtime entity so that it is part of the world digest (a
replay reproduces it bit for bit); `PrpAnatomy` is a resource read once from the pack's
[points], [planes], [foramina] and [paths] tables.

Anatomy names. The pack names points per side; several spellings are accepted so that an anatomy
file can use the clinical or the lay word. For side S in (left, right):

    oral commissure      oral_commissure_S | mouth_angle_S | mouth_corner_S | commissure_S
    pupil (medial)       pupil_medial_S | medial_pupil_S | pupil_S
    tragus / EAM         tragus_S | eam_S | external_auditory_meatus_S | ear_S
    planes (d1, d2, d3)  axial_mouth_S | sagittal_pupil_S | axial_ear_S (also without _S, and a
                         few variants); a plane that is not given is the axial (normal +Z) or
                         sagittal (normal +X) plane through the point above, which is what 6.1.5 defines.
    foramen              [foramina.S] (centre, radius_mm);  reference path [paths.S] (optional)
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from chainsim.engine.errors import UserError

SIDES = ("left", "right")
LANDMARK_COUNT = 3

POINT_ALIASES = {
    "mouth": ("oral_commissure_{s}", "mouth_angle_{s}", "mouth_corner_{s}", "commissure_{s}", "angle_of_mouth_{s}"),
    "pupil": ("pupil_medial_{s}", "medial_pupil_{s}", "pupil_{s}", "pupil_medial_aspect_{s}"),
    "tragus": ("tragus_{s}", "eam_{s}", "external_auditory_meatus_{s}", "ear_{s}", "ear_canal_{s}"),
}
PLANE_ALIASES = {
    "mouth": (
        "axial_mouth_{s}",
        "mouth_axial_{s}",
        "axial_oral_commissure_{s}",
        "axial_commissure_{s}",
        "axial_mouth",
        "mouth_axial",
        "axial_oral_commissure",
    ),
    "pupil": ("sagittal_pupil_{s}", "pupil_sagittal_{s}", "saggital_pupil_{s}", "sagittal_{s}"),
    "tragus": ("axial_ear_{s}", "ear_axial_{s}", "axial_tragus_{s}", "axial_eam_{s}", "axial_ear", "axial_tragus"),
}
DEFAULT_NORMAL = {"mouth": (0.0, 0.0, 1.0), "pupil": (1.0, 0.0, 0.0), "tragus": (0.0, 0.0, 1.0)}

#: ideal distances of 6.1.5: landmark 1 is 25 mm from the mouth angle, landmark 2 on the pupil,
#: landmark 3 30 mm from the tragus
IDEAL_MM = {"mouth": 25.0, "pupil": 0.0, "tragus": 30.0}
LANDMARK_ROLES = ("mouth", "pupil", "tragus")  # landmark k is measured against role k


@dataclass(slots=True)
class Plane:
    point: np.ndarray
    normal: np.ndarray  # unit

    def distance(self, p) -> float:
        return float(abs((np.asarray(p, float) - self.point) @ self.normal))


@dataclass(slots=True)
class SideAnatomy:
    side: str
    points: dict[str, np.ndarray]  # role -> position (mouth, pupil, tragus)
    planes: dict[str, Plane]  # role -> plane for d1, d2, d3
    foramen_centre: np.ndarray
    foramen_radius: float
    foramen_axis: np.ndarray
    path_entry: np.ndarray | None = None
    path_target: np.ndarray | None = None
    path_clear: bool = False


@dataclass(slots=True)
class PrpAnatomy:
    """Named anatomy of both sides (resource)."""

    sides: dict[str, SideAnatomy]

    def side_of(self, point) -> str:
        """The side whose sagittal half holds the point: the nearer of the two foramina across the
        midline. Decided from the named anatomy, so it holds whichever way a pack's axes point."""
        p = np.asarray(point, float)
        left, right = self.sides["left"].foramen_centre, self.sides["right"].foramen_centre
        across = right - left
        return "left" if (p - 0.5 * (left + right)) @ across < 0.0 else "right"


def _lookup(table: dict, aliases, side: str):
    for a in aliases:
        name = a.format(s=side)
        if name in table:
            return name, table[name]
    return None, None


def anatomy_from_pack(pack) -> PrpAnatomy:
    """Read both sides' points, planes, foramina and paths; one UserError line if something is missing."""
    points = pack.section("points")
    planes = pack.section("planes")
    foramina = pack.section("foramina")
    paths = pack.section("paths")
    sides = {}
    for s in SIDES:
        pts, pls = {}, {}
        for role, aliases in POINT_ALIASES.items():
            name, spec = _lookup(points, aliases, s)
            if spec is None:
                want = " or ".join(f"[points.{a.format(s=s)}]" for a in aliases[:2])
                raise UserError(
                    f"pack '{pack.name}': the rhizotomy procedure needs {want} "
                    f"(known points: {', '.join(sorted(points)) or 'none'})"
                )
            pts[role] = np.asarray(spec["position"], dtype=np.float64)
        for role, aliases in PLANE_ALIASES.items():
            name, spec = _lookup(planes, aliases, s)
            if spec is not None:
                n = np.asarray(spec["normal"], dtype=np.float64)
                if np.linalg.norm(n) < 1e-12:
                    raise UserError(f"pack '{pack.name}': [planes.{name}] normal must not be zero")
                pls[role] = Plane(np.asarray(spec["point"], dtype=np.float64), n / np.linalg.norm(n))
            else:
                pls[role] = Plane(pts[role].copy(), np.asarray(DEFAULT_NORMAL[role], dtype=np.float64))
        fo = foramina.get(s)
        if fo is None:
            raise UserError(f"pack '{pack.name}': the rhizotomy procedure needs [foramina.{s}] (centre, radius_mm)")
        ax = np.asarray(fo["axis"], dtype=np.float64)
        ax = ax / np.linalg.norm(ax) if np.linalg.norm(ax) > 1e-12 else np.array([0.0, 0.0, 1.0])
        sa = SideAnatomy(s, pts, pls, np.asarray(fo["centre"], dtype=np.float64), float(fo["radius_mm"]), ax)
        pa = paths.get(s)
        if pa is not None:
            sa.path_entry = np.asarray(pa["entry"], dtype=np.float64)
            sa.path_target = np.asarray(pa["target"], dtype=np.float64)
            sa.path_clear = bool(pa.get("clear", False))
        sides[s] = sa
    return PrpAnatomy(sides)


def landmark_errors(anat: SideAnatomy, landmarks: np.ndarray) -> dict:
    """Thesis 6.1.5: D1 = |Dist1 - 25|, D2 = Dist2, D3 = |Dist3 - 30|; d_k = distance to plane k;
    E = ((D1 + d1) + (D2 + d2) + (D3 + d3)) / 6, all in mm. Unplaced landmarks give None."""
    out: dict = {}
    total = 0.0
    complete = True
    for k, role in enumerate(LANDMARK_ROLES, start=1):
        p = landmarks[k - 1]
        if not np.all(np.isfinite(p)):
            out[f"D{k}"] = None
            out[f"d{k}"] = None
            complete = False
            continue
        dist = float(np.linalg.norm(p - anat.points[role]))
        big = abs(dist - IDEAL_MM[role])
        small = anat.planes[role].distance(p)
        out[f"Dist{k}"] = dist
        out[f"D{k}"] = big
        out[f"d{k}"] = small
        total += big + small
    out["landmark_error_mm"] = total / 6.0 if complete else None
    return out


@dataclass(slots=True)
class ProcedureState:
    """Where the trainee is in the procedure, and what the assessment needs (runtime component)."""

    step_ids: list[str] = field(default_factory=list)
    step: int = 0
    step_started: float = 0.0  # simulated seconds
    step_times: dict[str, float] = field(default_factory=dict)
    landmarks: np.ndarray = field(default_factory=lambda: np.full((LANDMARK_COUNT, 3), np.nan))
    placed: int = 0
    side: str = ""
    aids: dict[str, bool] = field(default_factory=dict)  # on at any time during the attempt
    aids_now: dict[str, bool] = field(default_factory=dict)  # on at this moment
    lights: dict[str, str] = field(default_factory=dict)  # recorded even when the signals are hidden
    elapsed: float = 0.0  # simulated seconds of the attempt
    target: str = "none"  # object the needle touched last
    needle_dist: float = float("nan")  # Dist of E = Dist - R at the last contact (mm)
    hit_point: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    started_at: float = 0.0
    finished: bool = False
    # ids the records store gave to saved attempts: a side effect outside the simulation, so not part
    # of the world digest (a replay, which never saves, must reach the recorded digest)
    saved: list[int] = field(default_factory=list, metadata={"digest": False})
    attempt: int = 1  # attempts begun in this session
    closed: bool = False  # the attempt was saved: its clock stops, the next action begins another
    touched: bool = False  # anything done in this attempt (an unsaved attempt worth asking about)

    @property
    def step_id(self) -> str:
        return self.step_ids[self.step] if self.step_ids else ""

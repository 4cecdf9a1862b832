"""The needle-procedure vocabulary: what a pack declares, how it is read, and the trainee's progress.

A needle procedure (thesis 3.2.3 task analysis, 3.3.4 interface, 3.3.6 feedback, 6.1.5 scoring) is
described entirely by pack data, read by the generic systems in chainsim.systems.procedures.needle:

    [needle_procedure]   sides, which landmark places the needle and decides the side, the landmark
                         score, aids, lights, where Reset goes back to
    [roles.NAME]         what entities are: skin (clicked, entered), target (an opening with a radius),
                         obstacle (bounce | stop | warn on contact), tissue (deformable, not an obstacle)
    [[landmarks]]        the points the trainee clicks, in order, each scored by its distance to a
                         named point (minus an ideal distance) and to a named plane
    [[steps]]            (the shell's table, game/packs/declarations.py) gain `landmark` (STEP_FIELDS, here);
                         `done_on` names this procedure's events
    [[feedback]]         per event: a message, a light and its colour
    [metrics.NAME]       (the shell's table) gain `measure`, `role`, `step` (METRIC_FIELDS, here): which
                         value of the vocabulary is stored
    [foramina.NAME]      the target openings a role's `opening` names

Every key is declared here with `section()`, so `chainsim validate` checks it and `chainsim docs
components` lists it; docs/needle-procedures.md is the modder's guide. A text may contain `{side}`,
replaced by the side the trainee works on (the entry of `sides` whose target centre is nearest the
landmark named by `side_from`).

`NeedleScene` is the resource read once from those tables; `ProcedureState` lives on a runtime entity
so it is part of the world digest (a replay reproduces it bit for bit).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from chainsim.components.registry import Field, section
from chainsim.systems.engine.errors import UserError

ROLE_KINDS = ("skin", "target", "obstacle", "tissue")
ON_CONTACT = ("bounce", "stop", "warn")
LANDMARK_SCORES = ("thesis-6.1.5", "mean-distance", "none")
LIGHT_COLOURS = ("", "off", "red", "green", "yellow")
MEASURES = (
    "",
    "duration",
    "step_time",
    "path_length",
    "contacts",
    "first_contact_distance",
    "needle_error",
    "landmark_error",
    "redirections",
    "refused_rotations",
    "xray_shots",
    "exposure",
    "dose",
    "peak_force",
    "punctures",
    "repunctures",
    "device_peak_force",
    "puncture_force",
    "bone_contact_time",
)

section(
    "needle_procedure",
    "table",
    "How the generic needle procedure (pack.procedure = 'needle') runs this pack (docs/needle-procedures.md).",
    [
        Field(
            "sides",
            "str_list",
            [],
            help="Side names substituted for {side} in entity, point, plane and opening names (e.g. left, right); "
            "empty: one side, {side} is replaced by nothing.",
        ),
        Field(
            "side_from",
            "str",
            "",
            help="Landmark id whose position decides the side: the side whose target centre is nearest "
            "(default: the entry landmark).",
        ),
        Field(
            "entry",
            "str",
            "",
            help="Landmark id where the needle enters the skin; placing it places the needle (default: the first).",
        ),
        Field(
            "landmark_score",
            "enum",
            "thesis-6.1.5",
            choices=LANDMARK_SCORES,
            help="thesis-6.1.5: E = sum over landmarks of (D_k + d_k) / (2 n), D_k = |distance to its point - "
            "ideal_mm|, d_k = distance to its plane; mean-distance: mean of D_k; none: no landmark error.",
        ),
        Field("target", "str", "", help="Role name of the target (default: the first role with role = 'target')."),
        Field(
            "aids",
            "str_list",
            [],
            help="Toggle widgets recorded per attempt as aids (on at any time of the attempt counts).",
        ),
        Field("lights", "str_list", [], help="Light widgets the feedback drives; all go off at a reset."),
        Field("signals_aid", "str", "", help="Toggle that shows the lights (off: the lights stay dark)."),
        Field("planes_aid", "str", "", help="Toggle that shows the planes through the placed landmarks."),
        Field(
            "reset_step",
            "str",
            "",
            help="Step a Reset returns to once the entry landmark is placed (default: the step after the last "
            "landmark step).",
        ),
        Field("reset_all_step", "str", "", help="Step a shift+Reset returns to (default: the first landmark step)."),
        Field(
            "ideal_path",
            "str",
            "",
            help="[paths] name ({side} allowed) of the ideal needle path, drawn against the trainee's in the "
            "debrief; empty: none drawn.",
        ),
        Field(
            "fluoro_first",
            "bool",
            False,
            help="Fluoroscopy first: the tip view shows no target ring or distance, so the trainee guides by X-ray "
            "(play/run --fluoro-first turns it on too); the assessment records the mode.",
        ),
    ],
)

section(
    "roles",
    "named",
    "What some entities are to the needle procedure (skin, target, obstacle, tissue).",
    [
        Field(
            "role",
            "enum",
            choices=ROLE_KINDS,
            help="skin: the entry surface, clicked for landmarks; target: what the needle must reach (it stops "
            "there and the attempt's clock stops); obstacle: stops or warns the needle; tissue: deformable, "
            "not an obstacle.",
        ),
        Field("entities", "str_list", [], help="Entity names ({side} allowed) that play this role."),
        Field(
            "on_contact",
            "enum",
            "bounce",
            choices=ON_CONTACT,
            help="Obstacles: bounce (the tip springs back by the needle's bounce, thesis 3.3.6), stop (it stays "
            "where it touched), warn (it passes, the contact is counted and signalled).",
        ),
        Field(
            "labels",
            "str_list",
            [],
            help="How messages name each entity, in the order of `entities` ({what}); default: the entity name.",
        ),
        Field("opening", "str", "", help="Targets: a [foramina] entry ({side} allowed) giving centre, radius, axis."),
        Field("point", "str", "", help="Targets without an opening: a [points] entry ({side} allowed), the centre."),
        Field("radius_mm", "float", 0.0, units="mm", help="Targets without an opening: the radius R.", min=0.0),
    ],
)

section(
    "landmarks",
    "list",
    "A landmark the trainee clicks on the skin, in order, and how it is scored (thesis 3.3.4, 6.1.5).",
    [
        Field("id", "str", help="Landmark identifier (used by steps and feedback: landmark:ID)."),
        Field("on", "str", "skin", help="Role whose entities accept the click."),
        Field("marker", "entity", "", help="Entity with a marker shown where the landmark is placed."),
        Field("plane_entity", "entity", "", help="Entity (a thin box) moved onto the plane through the landmark."),
        Field("plane_normal", "vec3", [0.0, 0.0, 1.0], help="Normal of that plane (the box's local +Z)."),
        Field("plane_up", "vec3", [0.0, 1.0, 0.0], help="The box's local +Y direction."),
        Field(
            "points",
            "str_list",
            [],
            help="[points] names it is measured against, first found wins ({side} allowed); empty: not scored.",
        ),
        Field("ideal_mm", "float", 0.0, units="mm", help="Ideal distance to that point: D = |Dist - ideal_mm|."),
        Field(
            "planes", "str_list", [], help="[planes] names for d (distance to the plane), first found wins ({side})."
        ),
        Field(
            "plane_through",
            "str_list",
            [],
            help="Instead of a named plane: three [points] names ({side} allowed); d is the distance to the plane "
            "through them.",
        ),
        Field(
            "plane_fallback",
            "vec3",
            [0.0, 0.0, 0.0],
            help="Normal of the plane through the point used when no named plane is found (zero: none, d = 0).",
        ),
        Field("score_label", "str", "", help="How the assessment panel names what it is measured against."),
    ],
)

section(
    "feedback",
    "list",
    "What the trainee sees or hears when an event happens (docs/needle-procedures.md lists the events).",
    [
        Field("on", "str", help="The event, e.g. 'contact:target', 'landmark:entry', 'refused:locked'."),
        Field("message", "str", "", help="HUD message; {names} are filled from the event."),
        Field("light", "str", "", help="Light widget set by the event (every other light goes off)."),
        Field("color", "enum", "", choices=LIGHT_COLOURS, help="Colour of that light."),
    ],
)

section(
    "foramina",
    "named",
    "A target opening for a needle.",
    [
        Field("centre", "vec3", units="mm", help="Centre of the opening."),
        Field("axis", "vec3", help="Direction through the opening."),
        Field("width_mm", "float", units="mm", help="Long axis of the opening.", min=0.0),
        Field("height_mm", "float", units="mm", help="Short axis of the opening.", min=0.0),
        Field("radius_mm", "float", units="mm", help="Radius R used by the needle error E = Dist - R.", min=0.0),
        Field("help", "str", "", help="Notes."),
    ],
)

# -- this procedure's part in the shell's shared tables (chainsim.game.packs.declarations) ----------------------
#
# [pack], [[steps]] and [metrics.NAME] are declared by the shell for every procedure; what they say of
# the needle procedure, and the keys only it reads, are declared here, with the rest of its vocabulary.

#: pack.procedure's help: what the procedure 'needle' is
PROCEDURE_HELP = (
    "the generic needle procedure its [needle_procedure], [roles], [[landmarks]], [[steps]] and [[feedback]] "
    "describe; 'prp' is its old name"
)
#: the events a step's done_on may name (the full list: docs/needle-procedures.md)
DONE_ON_HELP = "click:ROLE, landmark:ID, dial:WIDGET, depth, contact:ROLE, button:WIDGET"
#: the keys a [[steps]] table has for this procedure
STEP_FIELDS = (
    Field(
        "landmark",
        "str",
        "",
        help="Needle procedure: the landmark placed in this step; Next cannot leave the step before it is placed.",
    ),
)
#: the keys a [metrics.NAME] table has for this procedure: which value of the vocabulary it stores
METRIC_FIELDS = (
    Field(
        "measure",
        "enum",
        "",
        choices=MEASURES,
        help="Needle procedure: which value of the vocabulary this metric is (duration s, step_time s of "
        "`step`, path_length mm, contacts with `role`, first_contact_distance mm tip to target centre, "
        "needle_error mm = Dist - R at the last contact, landmark_error mm, redirections, refused_rotations, "
        "xray_shots, exposure s, dose mGy, peak_force N axial on the needle, punctures of `layer`, repunctures: the "
        "skin punctured again at a new place; with a force-feedback device: device_peak_force N the hand felt, "
        "puncture_force N when the first layer gave, bone_contact_time s held against bone); stored per attempt "
        "in the records' metrics table under this "
        "metric's name. Empty: the assessment value of the same name, if any.",
    ),
    Field("role", "str", "", help="measure = contacts: the role whose contacts are counted."),
    Field("step", "str", "", help="measure = step_time: the step timed."),
    Field("layer", "str", "", help="measure = punctures: the [tissue_layers] layer whose punctures are counted."),
)


@dataclass(slots=True)
class Plane:
    point: np.ndarray
    normal: np.ndarray  # unit

    def distance(self, p) -> float:
        return float(abs((np.asarray(p, float) - self.point) @ self.normal))


@dataclass(slots=True)
class LandmarkTarget:
    """What one landmark is scored against on one side: a point (with an ideal distance) and a plane."""

    point: np.ndarray | None = None
    ideal_mm: float = 0.0
    plane: Plane | None = None


@dataclass(slots=True)
class Target:
    """The target on one side: the entities that count as reaching it, its centre, radius and axis."""

    entities: tuple[str, ...]
    centre: np.ndarray
    radius: float
    axis: np.ndarray


@dataclass(slots=True)
class Role:
    name: str
    kind: str
    entities: tuple[str, ...]  # every side's names
    on_contact: str = "bounce"
    labels: dict[str, str] = field(default_factory=dict)  # entity -> how messages name it


@dataclass(slots=True)
class NeedleScene:
    """The pack's needle procedure, resolved (resource, read once)."""

    sides: tuple[str, ...]
    roles: dict[str, Role]
    target_role: str
    targets: dict[str, Target]  # side -> target
    landmark_ids: tuple[str, ...]
    landmark_specs: list[dict]
    landmark_targets: dict[str, list[LandmarkTarget]]  # side -> per landmark
    entry: int = 0  # index of the entry landmark
    side_from: int = 0
    landmark_score: str = "thesis-6.1.5"

    def side_of(self, point) -> str:
        """The side whose target centre is nearest the point (the sagittal half it lies in, for two sides)."""
        if len(self.sides) == 1:
            return self.sides[0]
        p = np.asarray(point, float)
        return min(self.sides, key=lambda s: float(np.linalg.norm(p - self.targets[s].centre)))

    def target(self, side: str) -> Target:
        return self.targets.get(side) or self.targets[self.sides[0]]

    def role_of(self, entity: str, side: str) -> Role | None:
        """The role an entity plays on `side`: the side's target first, then any other role listing it."""
        if entity in self.target(side).entities:
            return self.roles[self.target_role]
        for r in self.roles.values():
            if r.kind != "target" and entity in r.entities:
                return r
        return None

    def label(self, entity: str) -> str:
        for r in self.roles.values():
            if entity in r.labels:
                return r.labels[entity]
        return entity.replace("_", " ")

    def obstacles(self) -> list[str]:
        """Every entity the needle can touch (targets of all sides and obstacles), each once, in role order."""
        out: list[str] = []
        for r in self.roles.values():
            if r.kind in ("target", "obstacle"):
                out += [e for e in r.entities if e not in out]
        return out


def expand(name: str, sides) -> list[str]:
    """`name` for each side when it holds {side}; else the name itself."""
    return [name.format(side=s) for s in sides] if "{side}" in name else [name]


def _first(table: dict, names, side: str):
    for n in names:
        key = n.format(side=side)
        if key in table:
            return key, table[key]
    return None, None


def _role(name: str, spec: dict, sides) -> Role:
    """A [roles.NAME] table: its entities (a `{side}` name once per side) and their labels."""
    ents: list[str] = []
    labels: dict[str, str] = {}
    names = spec.get("labels", [])
    for i, e in enumerate(spec.get("entities", [])):
        for s in sides if "{side}" in e else ("",):
            one = e.format(side=s)
            if one not in ents:
                ents.append(one)
            if i < len(names):
                labels[one] = names[i].format(side=s)
    return Role(name, spec["role"], tuple(ents), spec.get("on_contact", "bounce"), labels)


def _target(target_role: str, tspec: dict, s: str, foramina, points, where: str) -> Target:
    """The target on side `s`: its opening ([foramina]: centre, radius and axis) or its point."""
    target_ents = tuple(e.format(side=s) for e in tspec.get("entities", []))
    if tspec.get("opening"):
        key = tspec["opening"].format(side=s)
        fo = foramina.get(key)
        if fo is None:
            raise UserError(f"{where}: [roles.{target_role}] opening needs [foramina.{key}] (centre, radius_mm)")
        ax = np.asarray(fo["axis"], dtype=np.float64)
        ax = ax / np.linalg.norm(ax) if np.linalg.norm(ax) > 1e-12 else np.array([0.0, 0.0, 1.0])
        return Target(target_ents, np.asarray(fo["centre"], dtype=np.float64), float(fo["radius_mm"]), ax)
    key = tspec.get("point", "").format(side=s)
    if key not in points:
        raise UserError(
            f"{where}: [roles.{target_role}] needs an opening ([foramina]) or a point ([points.{key or 'NAME'}])"
        )
    c = np.asarray(points[key]["position"], dtype=np.float64)
    return Target(target_ents, c, float(tspec.get("radius_mm", 0.0)), np.array([0.0, 0.0, 1.0]))


def _landmark_target(sp: dict, s: str, points, planes, where: str) -> LandmarkTarget:
    """Where a [[landmarks]] entry should be on side `s`: its point and its plane (named, through three
    points, or the fallback normal through the point)."""
    t = LandmarkTarget(ideal_mm=float(sp.get("ideal_mm", 0.0)))
    if sp.get("points"):
        _name, p = _first(points, sp["points"], s)
        if p is None:
            want = " or ".join(f"[points.{n.format(side=s)}]" for n in sp["points"][:2])
            known = ", ".join(sorted(points)) or "none"
            raise UserError(f"{where}: landmark '{sp['id']}' needs {want} (known points: {known})")
        t.point = np.asarray(p["position"], dtype=np.float64)
    pname, pl = _first(planes, sp.get("planes", []), s)
    through = sp.get("plane_through") or []
    if pl is None and through:
        pl = _plane_through(points, [n.format(side=s) for n in through], f"{where}: landmark '{sp['id']}'")
        pname = "plane_through"
    if pl is not None:
        n = np.asarray(pl["normal"], dtype=np.float64)
        if np.linalg.norm(n) < 1e-12:
            raise UserError(f"{where}: [planes.{pname}] normal must not be zero")
        t.plane = Plane(np.asarray(pl["point"], dtype=np.float64), n / np.linalg.norm(n))
    elif t.point is not None and np.linalg.norm(sp.get("plane_fallback", np.zeros(3))) > 1e-12:
        n = np.asarray(sp["plane_fallback"], dtype=np.float64)
        t.plane = Plane(t.point.copy(), n / np.linalg.norm(n))
    return t


def scene_from_pack(pack) -> NeedleScene:
    """Read the needle-procedure tables; one UserError line for what is missing or inconsistent."""
    np_ = pack.section("needle_procedure")
    sides = tuple(np_.get("sides") or ()) or ("",)
    points, planes, foramina = pack.section("points"), pack.section("planes"), pack.section("foramina")
    where = f"pack '{pack.name}'"
    roles = {name: _role(name, spec, sides) for name, spec in pack.section("roles").items()}
    target_role = np_.get("target") or next((n for n, r in roles.items() if r.kind == "target"), "")
    if target_role not in roles or roles[target_role].kind != "target":
        raise UserError(f"{where}: the needle procedure needs a [roles.NAME] with role = 'target'")
    tspec = pack.section("roles")[target_role]
    targets = {s: _target(target_role, tspec, s, foramina, points, where) for s in sides}
    specs = list(pack.section("landmarks"))
    ids = tuple(sp["id"] for sp in specs)
    if len(set(ids)) != len(ids):
        raise UserError(f"{where}: two [[landmarks]] share an id ({', '.join(ids)})")
    lt = {s: [_landmark_target(sp, s, points, planes, where) for sp in specs] for s in sides}

    def index_of(key: str, default: int) -> int:
        lid = np_.get(key) or ""
        if not lid:
            return default
        if lid not in ids:
            raise UserError(f"{where}: needle_procedure.{key} = '{lid}' is not a landmark id ({', '.join(ids)})")
        return ids.index(lid)

    entry = index_of("entry", 0)
    return NeedleScene(
        sides=sides,
        roles=roles,
        target_role=target_role,
        targets=targets,
        landmark_ids=ids,
        landmark_specs=specs,
        landmark_targets=lt,
        entry=entry,
        side_from=index_of("side_from", entry),
        landmark_score=np_.get("landmark_score", "thesis-6.1.5"),
    )


def _plane_through(points: dict, names: list[str], where: str) -> dict:
    """{point, normal} of the plane through three named points; one UserError line if it is not one."""
    missing = [n for n in names if n not in points]
    if len(names) != 3 or missing:
        raise UserError(f"{where}: plane_through needs three [points] names ({', '.join(missing) or len(names)})")
    a, b, c = (np.asarray(points[n]["position"], dtype=np.float64) for n in names)
    n = np.cross(b - a, c - a)
    if np.linalg.norm(n) < 1e-9:
        raise UserError(f"{where}: plane_through points {', '.join(names)} lie on one line")
    return {"point": a, "normal": n}


def landmark_errors(targets: list[LandmarkTarget], landmarks: np.ndarray, score: str = "thesis-6.1.5") -> dict:
    """Per landmark k (1-based): Dist_k to its point, D_k = |Dist_k - ideal_k|, d_k to its plane (0 without
    one). thesis-6.1.5: E = sum(D_k + d_k) / (2 n) (6.1.5's ((D1 + d1) + (D2 + d2) + (D3 + d3)) / 6 for
    three); mean-distance: E = mean D_k. All mm; E is None until every landmark is placed."""
    out: dict = {}
    big_sum = small_sum = 0.0
    complete = True
    for k, t in enumerate(targets, start=1):
        p = landmarks[k - 1]
        if not np.all(np.isfinite(p)):
            out[f"D{k}"] = None
            out[f"d{k}"] = None
            complete = False
            continue
        if t.point is not None:
            dist = float(np.linalg.norm(p - t.point))
            out[f"Dist{k}"] = dist
            out[f"D{k}"] = abs(dist - t.ideal_mm)
            big_sum += out[f"D{k}"]
        else:
            out[f"D{k}"] = 0.0
        out[f"d{k}"] = t.plane.distance(p) if t.plane is not None else 0.0
        small_sum += out[f"d{k}"]
    n = len(targets)
    if not complete or n == 0 or score == "none":
        out["landmark_error_mm"] = None
    elif score == "mean-distance":
        out["landmark_error_mm"] = big_sum / n
    else:
        out["landmark_error_mm"] = (big_sum + small_sum) / (2.0 * n)
    return out


@dataclass(slots=True)
class ProcedureState:
    """Where the trainee is in the procedure, and what the assessment needs (runtime component)."""

    step_ids: list[str] = field(default_factory=list)
    step: int = 0
    step_started: float = 0.0  # simulated seconds
    step_times: dict[str, float] = field(default_factory=dict)
    landmarks: np.ndarray = field(default_factory=lambda: np.full((0, 3), np.nan))
    placed: int = 0
    side: str = ""
    aids: dict[str, bool] = field(default_factory=dict)  # on at any time during the attempt
    aids_now: dict[str, bool] = field(default_factory=dict)  # on at this moment
    lights: dict[str, str] = field(default_factory=dict)  # recorded even when the signals are hidden
    elapsed: float = 0.0  # simulated seconds of the attempt
    target: str = "none"  # object the needle touched last
    needle_dist: float = float("nan")  # Dist of E = Dist - R at the last contact (mm)
    first_dist: float = float("nan")  # the same at the attempt's first contact (mm)
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

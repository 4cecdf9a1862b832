"""What `chainsim validate` checks of a needle pack before any scene starts: every text the procedure
formats and every name its tables refer to.

A pack that passes these checks cannot fail a trainee at run time through its own data: each
[[feedback]] message is formatted here against the values its event gives (procedure.py `say`), with
the types they have, so a bad format spec, an unbalanced brace or an unknown field is one line now
and not a traceback when the needle reaches the target; every `{side}` name is formatted for each
side and must name what exists; steps, roles, landmarks, aids and metrics resolve. `problems(man)`
returns (key path, message) pairs; chainsim.game.packs.validation places them as validate problems and
adds the limits of the records store.
"""

from __future__ import annotations

import functools
import re
import string
from typing import Any

import numpy as np

from chainsim.systems.procedures.needle.kinematics import ROTATION_WIDGETS

_STR, _INT, _FLOAT = "text", 1, 1.5  # sample values of each type a message may be given

#: the values each event's message is formatted with, one dict per place that says it (a field missing
#: from one of them shows as `{name}` there, so it may take no format spec a text cannot)
MESSAGE_VALUES: dict[str, list[dict[str, Any]]] = {
    "click_elsewhere": [{"entity": _STR, "n": _INT}],
    "landmarks_full": [{}],
    "landmark": [{"n": _INT, "side": _STR, "id": _STR}],
    "landmark_missing": [{"n": _INT, "instruction": _STR}],
    "attempt": [{"attempt": _INT}],
    "button": [{}],
    "reset": [{}],
    "reset_all": [{}],
    "refused:locked": [{}, {"n": _INT}],
    "refused": [{"n": _INT}],
    "withdrawn": [{}, {"n": _INT}],
    "turn_held": [{"n": _INT}],
    "turns_dropped": [{"n": _INT}],
    "contact": [{"what": _STR, "dist_mm": _FLOAT, "error_mm": _FLOAT, "radius_mm": _FLOAT, "side": _STR}],
    "contact_again": [
        {"what": _STR, "dist_mm": _FLOAT, "error_mm": _FLOAT, "radius_mm": _FLOAT, "side": _STR, "withdraw_mm": _FLOAT}
    ],
    # events a step may be done on that say nothing: a message there is never shown
    "click": [{}],
    "dial": [{}],
    "depth": [{}],
}
EVENT_KINDS = tuple(k for k in MESSAGE_VALUES if ":" not in k)
REFUSALS = ("locked", "not_placed", "in_target", "max_depth")
#: `{side}` is the only field of entity, point, plane, opening and label names
SIDE_VALUES = [{"side": _STR}]


class _Blank(dict):
    """As the HUD formats messages: a field the event does not give shows as `{name}`."""

    def __missing__(self, key):
        return "{" + key + "}"


def _fields(text: str) -> list[str]:
    """Every field name in a format string, those nested in format specs included; ValueError if unbalanced."""
    out = []
    for _lit, name, spec, _conv in string.Formatter().parse(text):
        if name is not None:
            out.append(name)
        if spec:
            out += _fields(spec)
    return out


def format_problem(text: str, values: list[dict[str, Any]], strict: bool = False) -> str:
    """Why `text` cannot be formatted with each of `values` (as the procedure formats it), or ""."""
    allowed = sorted({k for v in values for k in v})
    given = ", ".join("{" + k + "}" for k in allowed) or "none"
    try:
        for name in _fields(text):
            root = re.split(r"[.\[]", name, maxsplit=1)[0]
            if name != root:
                return f"'{{{name}}}': a field is a plain name, without . or [ ] (fields: {given})"
            if root not in allowed:
                what = f"unknown field '{{{name}}}'" if name else "'{}' names no field"
                return f"{what} (fields: {given}; write {{{{ and }}}} for a brace)"
        for v in values:
            if strict:
                text.format(**v)
            else:
                text.format_map(_Blank(v))
    except (ValueError, TypeError, KeyError, IndexError, AttributeError) as e:
        return f"cannot be formatted: {e} (fields: {given})"
    return ""


def event_values(event: str) -> list[dict[str, Any]]:
    """The values a message for `event` is formatted with (see MESSAGE_VALUES)."""
    kind = event.partition(":")[0]
    return MESSAGE_VALUES.get(event) or MESSAGE_VALUES.get(kind) or [{}]


def event_problem(ev: str, roles, landmarks) -> str:
    """Why `ev` is not an event of the needle procedure, or ""."""
    kind, colon, arg = ev.partition(":")
    if kind not in EVENT_KINDS:
        return f"'{ev}' is not an event of the needle procedure ({', '.join(EVENT_KINDS)}; docs/needle-procedures.md)"
    needs_arg = kind in ("click", "contact", "landmark", "dial", "refused", "button")
    if needs_arg != bool(colon):
        return f"'{ev}': {kind} {'needs' if needs_arg else 'takes no'} ':NAME'"
    if kind in ("click", "contact") and arg not in roles:
        return f"'{ev}': no role '{arg}' in [roles] (roles: {', '.join(roles) or 'none'})"
    if kind == "landmark" and arg not in landmarks:
        return f"'{ev}': no landmark '{arg}' (landmark ids: {', '.join(landmarks) or 'none'})"
    if kind == "dial" and arg not in ROTATION_WIDGETS:
        return f"'{ev}': the dials are {', '.join(ROTATION_WIDGETS)}"
    if kind == "refused" and arg not in REFUSALS:
        return f"'{ev}': refusals are {', '.join(REFUSALS)}"
    if kind == "button" and not arg:
        return f"'{ev}': name the button"
    return ""


def value_names(man: dict) -> set[str]:
    """The numeric assessment values a metric without `measure` may name (assessment.compute)."""
    roles = man.get("roles", {})
    target = man.get("needle_procedure", {}).get("target") or next(
        (n for n, r in roles.items() if r.get("role") == "target"), ""
    )
    names = {
        "landmark_error_mm",
        "needle_error_mm",
        "needle_dist_mm",
        "first_contact_dist_mm",
        "target_reached",
        "obstacle_contacts",
        "path_length_mm",
        "rotation_refused",
        "redirections",
        "attempt",
        "duration_s",
        "tip_to_target_mm",
        "depth_mm",
        "rotation_horizontal_deg",
        "rotation_vertical_deg",
        "rotation_locked",
        "xray_shots",
        "fluoro_s",
        "exposure_s",
        "dose_mgy",
        f"{target}_radius_mm",
    }
    names |= {f"{r}_contacts" for r, spec in roles.items() if spec.get("role") == "obstacle"}
    for k in range(1, len(man.get("landmarks", [])) + 1):
        names |= {f"D{k}", f"d{k}", f"Dist{k}"}
    return names


class _Tables:
    """The needle pack's tables `problems` reads, and the sides its `{side}` names are formatted for."""

    def __init__(self, man: dict) -> None:
        self.man = man
        self.npc = man.get("needle_procedure", {})
        self.roles: dict = man.get("roles", {})
        self.specs: list = man.get("landmarks", [])
        self.steps: list = man.get("steps", [])
        self.entities, self.points, self.planes, self.foramina = (
            man.get(k, {}) for k in ("entities", "points", "planes", "foramina")
        )
        self.sides = list(self.npc.get("sides") or [])
        self.each_side = self.sides or [""]

    @functools.cached_property
    def ids(self) -> list[str]:
        return [sp.get("id", "") for sp in self.specs]

    @functools.cached_property
    def step_ids(self) -> list[str]:
        return [st.get("id", "") for st in self.steps]

    def expand(self, name: str) -> list[str]:
        return [name.format(side=s) for s in self.each_side]


def problems(man: dict) -> list[tuple[str, str]]:
    """(key path, message) for everything in a needle pack's tables that would fail a run."""
    t = _Tables(man)
    out = _side_name_problems(t)
    if out:
        return out  # every {side} name below would only repeat these
    for check in (_role_problems, _landmark_problems, _step_problems, _metric_problems, _ideal_path_problems):
        out += check(t)
    return out


def _side_name_problems(t: _Tables) -> list[tuple[str, str]]:
    """Every {side} name formats for each side; with no sides listed, {side} has nothing to stand for."""
    out = []
    side_names: list[tuple[str, str]] = []
    for rname, r in t.roles.items():
        side_names += [(f"roles.{rname}.entities", e) for e in r.get("entities", [])]
        side_names += [(f"roles.{rname}.labels", e) for e in r.get("labels", [])]
        side_names += [(f"roles.{rname}.{k}", r[k]) for k in ("opening", "point") if r.get(k)]
    for i, sp in enumerate(t.specs):
        for k in ("points", "planes", "plane_through"):
            side_names += [(f"landmarks.{i}.{k}", n) for n in sp.get(k, [])]
    if isinstance(t.npc.get("ideal_path"), str) and t.npc["ideal_path"]:
        side_names.append(("needle_procedure.ideal_path", t.npc["ideal_path"]))  # the debrief formats it per side
    bad_names = set()
    for key, name in side_names:
        msg = format_problem(name, SIDE_VALUES, strict=True)
        if msg:
            out.append((key, f"'{name[:60]}' {msg}"))
            bad_names.add(name)
    uses_side = next(((k, n) for k, n in side_names if "{side}" in n and n not in bad_names), None)
    if not t.sides and uses_side:
        out.append(
            (
                "needle_procedure.sides",
                f"is empty, but {uses_side[0]} '{uses_side[1][:60]}' uses {{side}}; list the sides it stands "
                'for (e.g. sides = ["left", "right"]) or write the names without {side}',
            )
        )
    return out


def _role_problems(t: _Tables) -> list[tuple[str, str]]:
    """Roles: their entities exist; the target has an opening or a point on every side."""
    out = []
    roles, npc = t.roles, t.npc
    for rname, r in roles.items():
        for e in r.get("entities", []):
            missing = [x for x in t.expand(e) if x not in t.entities]
            if missing:
                known = ", ".join(sorted(t.entities)[:12]) or "none"
                out.append((f"roles.{rname}.entities", f"'{missing[0]}' is not an entity of the pack ({known})"))
                break
    target = npc.get("target") or next((n for n, r in roles.items() if r.get("role") == "target"), "")
    if not target or target not in roles or roles[target].get("role") != "target":
        key = "needle_procedure.target" if npc.get("target") else "roles"
        out.append((key, f"needs a [roles.NAME] with role = 'target'{f', not {target!r}' if target else ''}"))
    elif roles[target].get("opening"):
        for key in t.expand(roles[target]["opening"]):
            if key not in t.foramina:
                known = ", ".join(sorted(t.foramina)) or "none"
                out.append((f"roles.{target}.opening", f"no [foramina.{key}] (foramina: {known})"))
                break
    else:
        for key in t.expand(roles[target].get("point", "")):
            if key not in t.points:
                out.append((f"roles.{target}", f"needs an opening ([foramina]) or a point ([points.{key or 'NAME'}])"))
                break
    return out


def _landmark_problems(t: _Tables) -> list[tuple[str, str]]:
    """Landmarks: ids unique, their role, entities, points and planes on every side."""
    out = []
    if not t.specs:
        out.append(("landmarks", "the needle procedure needs at least one [[landmarks]] (the entry point)"))
    for i, sp in enumerate(t.specs):
        key = f"landmarks.{i}"
        if t.ids.count(sp.get("id")) > 1:
            out.append((f"{key}.id", f"duplicate landmark id '{sp.get('id')}'"))
        if sp.get("on") not in t.roles:
            out.append((f"{key}.on", f"no role '{sp.get('on')}' in [roles] (roles: {', '.join(t.roles) or 'none'})"))
        for k in ("marker", "plane_entity"):
            if sp.get(k) and sp[k] not in t.entities:
                out.append((f"{key}.{k}", f"no entity named '{sp[k]}'"))
        if sp.get("plane_entity"):  # the plane's box is turned to face plane_normal with plane_up up
            n, up = (np.asarray(sp.get(k, (0.0, 0.0, 0.0)), dtype=np.float64) for k in ("plane_normal", "plane_up"))
            if np.linalg.norm(n) < 1e-9:
                out.append((f"{key}.plane_normal", "must not be zero (the plane entity is turned to face it)"))
            elif np.linalg.norm(np.cross(n, up)) < 1e-9 * np.linalg.norm(n) * max(float(np.linalg.norm(up)), 1.0):
                out.append((f"{key}.plane_up", "must not be zero nor parallel to plane_normal"))
        out += _landmark_side_problems(t, key, sp)
        for n in sp.get("planes", []):
            for name in t.expand(n):
                if name in t.planes and np.linalg.norm(t.planes[name].get("normal", [0, 0, 0])) < 1e-12:
                    out.append((f"planes.{name}.normal", "must not be zero"))
    for k in ("entry", "side_from"):
        if t.npc.get(k) and t.npc[k] not in t.ids:
            out.append((f"needle_procedure.{k}", f"'{t.npc[k]}' is not a landmark id ({', '.join(t.ids) or 'none'})"))
    return out


def _landmark_side_problems(t: _Tables, key: str, sp: dict) -> list[tuple[str, str]]:
    """A landmark's points, or the points its plane goes through, on every side (the first side that
    fails is named)."""
    for s in t.each_side:
        names = [n.format(side=s) for n in sp.get("points", [])]
        if names and not any(n in t.points for n in names):
            return [(f"{key}.points", f"none of {', '.join(names[:3])} is in [points]")]
        through = [n.format(side=s) for n in sp.get("plane_through", [])]
        if through and not any(n.format(side=s) in t.planes for n in sp.get("planes", [])):
            msg = _plane_through_problem(t.points, through)
            if msg:
                return [(f"{key}.plane_through", msg)]
    return []


def _step_problems(t: _Tables) -> list[tuple[str, str]]:
    """Steps, their events and the steps the procedure goes back to; feedback: its event, and its
    message formatted with the values that event gives; the aids the procedure reads."""
    out = []
    npc, ids, step_ids = t.npc, t.ids, t.step_ids
    for k in ("reset_step", "reset_all_step"):
        if npc.get(k) and npc[k] not in step_ids:
            out.append((f"needle_procedure.{k}", f"'{npc[k]}' is not a step id ({', '.join(step_ids) or 'none'})"))
    for i, st in enumerate(t.steps):
        if st.get("landmark") and st["landmark"] not in ids:
            out.append((f"steps.{i}.landmark", f"'{st['landmark']}' is not a landmark id ({', '.join(ids) or 'none'})"))
        for ev in st.get("done_on", []):
            msg = event_problem(ev, t.roles, ids)
            if msg:
                out.append((f"steps.{i}.done_on", msg))
                break
    for i, fb in enumerate(t.man.get("feedback", [])):
        ev = fb.get("on", "")
        msg = event_problem(ev, t.roles, ids)
        if msg:
            out.append((f"feedback.{i}.on", msg))
            continue
        msg = format_problem(fb.get("message", ""), event_values(ev))
        if msg:
            out.append((f"feedback.{i}.message", msg))
    aids = list(npc.get("aids", []))
    for k in ("signals_aid", "planes_aid"):
        if npc.get(k) and npc[k] not in aids:
            out.append((f"needle_procedure.{k}", f"'{npc[k]}' is not one of the aids ({', '.join(aids) or 'none'})"))
    return out


def _metric_problems(t: _Tables) -> list[tuple[str, str]]:
    """Metrics: what each measures resolves, and a critical value says what the error is."""
    out = []
    names = value_names(t.man)
    roles, step_ids = t.roles, t.step_ids
    for mname, m in t.man.get("metrics", {}).items():
        measure = m.get("measure", "")
        if measure == "step_time" and m.get("step") not in step_ids:
            out.append(
                (f"metrics.{mname}.step", f"'{m.get('step', '')}' is not a step id ({', '.join(step_ids) or 'none'})")
            )
        elif measure == "contacts" and m.get("role") not in roles:
            out.append((f"metrics.{mname}.role", f"'{m.get('role', '')}' is not a role ({', '.join(roles) or 'none'})"))
        elif not measure and mname not in names:
            out.append(
                (
                    f"metrics.{mname}.measure",
                    f"no measure, and '{mname}' is not an assessment value: give a measure "
                    "(docs/needle-procedures.md) or name the metric after a value",
                )
            )
        # a critical error the debrief could not name would fail an attempt without saying why
        if m.get("critical") is not None and not m.get("critical_note"):
            out.append((f"metrics.{mname}.critical_note", "a critical value needs a critical_note: the error in words"))
        # a benchmark said to rest on a study or on the programme's data must say which
        if m.get("benchmark_basis", "provisional") != "provisional" and not m.get("benchmark_source"):
            out.append(
                (
                    f"metrics.{mname}.benchmark_source",
                    f"benchmark_basis '{m['benchmark_basis']}' needs a benchmark_source: the publication and "
                    "population, or the programme's data",
                )
            )
    return out


def _ideal_path_problems(t: _Tables) -> list[tuple[str, str]]:
    """The debrief draws the ideal path on every side the trainee may work on."""
    ideal = t.npc.get("ideal_path", "")
    if not ideal:
        return []
    paths = t.man.get("paths", {})
    return [
        (
            "needle_procedure.ideal_path",
            f"no [paths.{ideal.format(side=side)}] (side '{side}'); known: {', '.join(paths) or 'none'}",
        )
        for side in t.each_side
        if ideal.format(side=side) not in paths
    ]


def hit_entities(man: dict) -> list[tuple[str, str]]:
    """(key, entity name) of every entity the needle can touch on any side: what an attempt stores as
    its `target` (targets of every side and obstacles)."""
    sides = list(man.get("needle_procedure", {}).get("sides") or []) or [""]
    out = []
    for rname, r in man.get("roles", {}).items():
        if r.get("role") in ("target", "obstacle"):
            for e in r.get("entities", []):
                # a name that does not format for each side is reported where names are checked
                if isinstance(e, str) and not format_problem(e, [{"side": s} for s in sides], strict=True):
                    out += [(f"roles.{rname}.entities", e.format(side=s)) for s in sides]
    return out


def _plane_through_problem(points: dict, names: list[str]) -> str:
    missing = [n for n in names if n not in points]
    if len(names) != 3 or missing:
        return f"needs three [points] names ({', '.join(missing) or len(names)})"
    a, b, c = (np.asarray(points[n]["position"], dtype=np.float64) for n in names)
    if np.linalg.norm(np.cross(b - a, c - a)) < 1e-9:
        return f"the points {', '.join(names)} lie on one line"
    return ""

"""Needle-procedure assessment: the landmark and needle errors, the attempt record and the assessment tool.

Thesis 3.3.4 (the tool, Fig. 3.11) and 6.1.5 (the error formulas). Stage: procedure
(ORDER_ASSESSMENT), after the procedure steps. Reads: ProcedureState, NeedleState, NeedleScene,
Widget events (self_assessment, save, help), Settings ("class", "trainee"), Records (where attempts
go; a replay's refuse every save, which then closes the attempt without storing it). A save that
did not happen is shown and appended to FailedSaves (a headless run then exits 2). Writes:
chainsim.game.trainer.headless.Assessment.values (the summary's `assessment`), HudState.panel_text and
messages; saves attempts to the records store.

Values, on the side the trainee works on (all millimetres unless said):
    landmark error  the pack's `landmark_score` over its [[landmarks]]
                    (chainsim.systems.procedures.needle.manifest.landmark_errors; D_k, d_k, Dist_k per landmark k)
    needle error    E = Dist - R at the last contact: Dist from the tip to the target centre, R the
                    target's radius. Negative when the tip stopped inside the radius; None while the
                    needle has touched nothing. `first_contact_dist_mm`: Dist at the first contact.
    contacts        `ROLE_contacts` per role touched (`contacts` all of them); ROLE_radius_mm for the target
Also: simulated seconds per step, the tip's path length while inserted, refused rotations,
redirections, the aids that were on at any time of the attempt, the object reached, and the X-ray
the attempt cost (thesis 3.2.3; .fluoro): single images `xray_shots`, live seconds `fluoro_s`, total
`exposure_s` and the estimated entrance dose `dose_mgy`.

The debrief (Self assessment, and every save) says each metric against the pack's benchmark, the
critical errors and one line of advice per failed metric (chainsim.systems.procedures.needle.debrief)
in HudState.debrief over the surgeon's view, and draws while it is shown the ideal landmarks and the
ideal path against the trainee's (entities with Marker and PolyLine; HudState.debrief_paths over the
last X-ray image). The attempt stores its thinned needle path and the ideal geometry in `details`.

The record saved per attempt keeps the records' fixed columns and adds `metrics`: every [metrics.NAME]
of the pack with its value (`measure` picks it from the vocabulary), stored in the procedure-neutral
metrics table (chainsim.game.records.migrations).
"""

from __future__ import annotations

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import Marker, PolyLine, Transform
from chainsim.components.input_events import Widget
from chainsim.components.resources import (
    Assessment,
    EntityIndex,
    FailedSaves,
    PackResource,
    Records,
    RunInfo,
    SavedLocally,
    Settings,
)
from chainsim.components.stages import ORDER_ASSESSMENT
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures import verdicts as vd
from chainsim.systems.procedures.needle import debrief as db
from chainsim.systems.procedures.needle import fluoro, haptics
from chainsim.systems.procedures.needle.carm import CArm
from chainsim.systems.procedures.needle.components import NeedleState
from chainsim.systems.procedures.needle.handles import NeedleHandles, hud
from chainsim.systems.procedures.needle.manifest import NeedleScene, ProcedureState, landmark_errors
from chainsim.systems.procedures.needle.tissue import NeedleTissue
from chainsim.systems.view.ui.widgets import format_value

DEFAULT_CLASS = "default"
DEFAULT_TRAINEE = "anonymous"


def _num(x):
    return None if x is None or not np.isfinite(x) else float(x)


def compute(app: App) -> dict:
    """The assessment values of the current attempt (JSON-ready)."""

    handles: NeedleHandles = app.resource(NeedleHandles)
    ps: ProcedureState = esper.component_for_entity(handles.procedure, ProcedureState)
    st: NeedleState = esper.component_for_entity(handles.needle, NeedleState)
    scene: NeedleScene = app.resource(NeedleScene)
    side = ps.side or scene.sides[0]
    target = scene.target(side)
    lm = landmark_errors(scene.landmark_targets[side], ps.landmarks, scene.landmark_score)
    radius = target.radius
    needle_error = None if not np.isfinite(ps.needle_dist) else ps.needle_dist - radius
    tip = st.tip() if st.placed else np.full(3, np.nan)
    obstacle_roles = [r.name for r in scene.roles.values() if r.kind == "obstacle"]
    out = {
        "side": ps.side or None,
        "step": ps.step_id,
        "landmark_error_mm": lm["landmark_error_mm"],
        "needle_error_mm": needle_error,
        "needle_dist_mm": _num(ps.needle_dist),
        "first_contact_dist_mm": _num(ps.first_dist),
        f"{scene.target_role}_radius_mm": radius,
        "target": ps.target,
        "target_reached": ps.finished,
        "contacts": {r: int(st.contacts.get(r, 0)) for r in scene.roles if r in st.contacts or r in obstacle_roles},
        "obstacle_contacts": int(sum(st.contacts.get(r, 0) for r in obstacle_roles)),
        "path_length_mm": float(st.path_length),
        "rotation_refused": int(st.rotation_refused),
        "redirections": int(st.redirections),
        "attempt": int(ps.attempt),
        "unsaved": bool(ps.touched and not ps.closed),
        "step_times": {k: float(v) for k, v in ps.step_times.items()},
        "aids": {k: bool(v) for k, v in ps.aids.items()},
        "fluoro_first": fluoro.fluoro_first(app),
        "duration_s": float(ps.elapsed),
        "landmarks": [None if not np.all(np.isfinite(p)) else [float(c) for c in p] for p in ps.landmarks],
        "hit_point": None if not np.all(np.isfinite(ps.hit_point)) else [float(c) for c in ps.hit_point],
        "tip": None if not st.placed else [float(c) for c in tip],
        "tip_to_target_mm": None if not st.placed else float(np.linalg.norm(tip - target.centre)),
        "depth_mm": float(st.depth),
        "rotation_horizontal_deg": float(st.yaw),
        "rotation_vertical_deg": float(st.pitch),
        "rotation_locked": bool(st.locked),
        "lights": dict(ps.lights),
    }
    for r in obstacle_roles:
        out[f"{r}_contacts"] = int(st.contacts.get(r, 0))
    out.update(xray_values(app))
    out.update(tissue_values(app, handles.needle))
    out.update(haptics.haptic_values(app))
    for k in range(1, len(scene.landmark_ids) + 1):
        out[f"D{k}"] = lm.get(f"D{k}")
        out[f"d{k}"] = lm.get(f"d{k}")
        out[f"Dist{k}"] = lm.get(f"Dist{k}")
    out["metrics"] = metric_values(app.resource(PackResource).pack, scene, out)
    return out


#: measure -> the assessment value it reads
MEASURE_KEYS = {
    "duration": "duration_s",
    "path_length": "path_length_mm",
    "first_contact_distance": "first_contact_dist_mm",
    "needle_error": "needle_error_mm",
    "landmark_error": "landmark_error_mm",
    "redirections": "redirections",
    "refused_rotations": "rotation_refused",
    "xray_shots": "xray_shots",
    "exposure": "exposure_s",
    "dose": "dose_mgy",
    "peak_force": "peak_axial_N",
    "repunctures": "repunctures",
    "device_peak_force": "device_peak_force_N",
    "puncture_force": "puncture_force_N",
    "bone_contact_time": "bone_contact_s",
}


def metric_values(pack, scene: NeedleScene, v: dict) -> dict:
    """The pack's [metrics.NAME] with their values (numbers or None), in the order declared."""
    out: dict = {}
    for name, spec in pack.section("metrics").items():
        m = spec.get("measure", "")
        if m == "contacts":
            x = v["contacts"].get(spec.get("role", ""), 0)
        elif m == "step_time":
            x = v["step_times"].get(spec.get("step", ""), 0.0)
        elif m == "punctures":
            x = v.get("punctures", {}).get(spec.get("layer", ""), 0)
        elif m:
            x = v.get(MEASURE_KEYS[m])
        else:
            x = v.get(name)
        out[name] = None if x is None or isinstance(x, (dict, list, str)) else float(x)
    return out


def tissue_values(app: App, needle: int) -> dict:
    """What the needle did to the tissue this attempt (none without tissue): peak axial force, punctures
    per layer, skin re-punctures (a new hole) and re-entries (through an old one)."""
    nt = esper.try_component(needle, NeedleTissue)
    if nt is None:
        return {}
    return {
        "peak_axial_N": float(nt.peak_axial),
        "punctures": {k: int(v) for k, v in nt.punctures.items()},
        "repunctures": int(nt.repunctures),
        "reentries": int(nt.reentries),
    }


def xray_values(app: App) -> dict:
    """The C-arm's counts for this attempt: single images, live seconds, exposure and dose (3.2.3)."""
    ent = app.resource(EntityIndex).get("carm")
    carm = esper.try_component(ent, CArm) if ent is not None else None
    if carm is None:
        return {"xray_shots": 0, "fluoro_s": 0.0, "exposure_s": 0.0, "dose_mgy": 0.0, "xray_view": None}
    return {
        "xray_shots": int(carm.shots),
        "fluoro_s": float(carm.live_s),
        "exposure_s": float(carm.exposure_s),
        "dose_mgy": float(carm.dose_mgy),
        "xray_view": carm.view,
    }


def panel_lines(v: dict, scene: NeedleScene, pack) -> list[str]:
    """The self-assessment text (Fig. 3.11's text field), each term said in words from the pack's tables."""

    def mm(x):
        return "-" if x is None else f"{format_value(x)} mm"

    n = len(scene.landmark_ids)
    lines = [
        f"Self assessment, attempt {v.get('attempt', 1)}"
        + (f" ({v['side']} side)" if v["side"] else "")
        + f": landmark error {mm(v['landmark_error_mm'])}, needle error {mm(v['needle_error_mm'])}"
    ]
    if n:
        ds = " / ".join(mm(v[f"D{k}"]) for k in range(1, n + 1))
        dp = " / ".join(mm(v[f"d{k}"]) for k in range(1, n + 1))
        to = ", ".join(sp.get("score_label") or sp["id"] for sp in scene.landmark_specs)
        lines.append(f"Landmark error: mean of D1-D{n} {ds} (to {to}) and d1-d{n} {dp} (to their planes)")
    what = (
        scene.label(scene.target(v["side"] or scene.sides[0]).entities[0])
        if scene.target(v["side"] or scene.sides[0]).entities
        else "the target"
    )
    lines.append(
        f"Needle error: tip to the centre of {what} {mm(v.get('needle_dist_mm'))} minus its radius "
        f"{mm(v.get(f'{scene.target_role}_radius_mm'))}, at the last contact"
    )
    labels = pack.section("metrics")

    def said(r: str) -> str:
        return labels.get(f"{r}_contacts", {}).get("label", r.replace("_", " ") + " contacts").lower()

    counts = "; ".join(f"{said(r)} {v[f'{r}_contacts']}" for r, role in scene.roles.items() if role.kind == "obstacle")
    lines.append(
        f"Reached {scene.label(v['target']) if v['target'] != 'none' else 'nothing'}"
        + (f"; {counts}" if counts else "")
        + f"; redirections {v.get('redirections', 0)}; path {v['path_length_mm']:.1f} mm; time {v['duration_s']:.1f} s"
    )
    lines.append(
        f"X-ray: {v.get('xray_shots', 0)} images, {v.get('fluoro_s', 0.0):.1f} s live; exposure "
        f"{v.get('exposure_s', 0.0):.1f} s, about {v.get('dose_mgy', 0.0):.2f} mGy to the skin"
    )
    on = [k.replace("_", " ") for k, x in v["aids"].items() if x]
    lines.append("Aids used: " + (", ".join(on) if on else "none"))
    return lines


def attempt_record(pack_name: str, v: dict) -> dict:
    """The records-store attempt (chainsim.game.records.store) for assessment values `v` (as in the summary).

    The fixed columns take what every needle procedure has (`skull_contacts` holds the contacts with
    every obstacle, a procedure without landmarks stores a landmark error of 0); `metrics` carries the
    pack's own [metrics] into the procedure-neutral table."""
    return {
        "pack": pack_name,
        "duration_s": v["duration_s"],
        "landmark_error_mm": v["landmark_error_mm"] if v["landmark_error_mm"] is not None else 0.0,
        "needle_error_mm": v["needle_error_mm"],
        "target": v["target"],
        "skull_contacts": v.get("obstacle_contacts", v.get("skull_contacts", 0)),
        "path_length_mm": v["path_length_mm"],
        "redirections": v.get("redirections", 0),
        "xray_shots": v.get("xray_shots", 0),
        "exposure_s": v.get("exposure_s", 0.0),
        "dose_mgy": v.get("dose_mgy", 0.0),
        "aids": v["aids"],
        "step_times": v["step_times"],
        "details": {
            k: v[k] for k in v if k in DETAIL_KEYS or k.endswith("_radius_mm") or (k[:1] in "Dd" and k[1:].isdigit())
        },
        "metrics": dict(v.get("metrics", {})),
    }


DETAIL_KEYS = (
    "side",
    "landmarks",
    "hit_point",
    "needle_dist_mm",
    "first_contact_dist_mm",
    "contacts",
    "rotation_refused",
    "rotation_horizontal_deg",
    "rotation_vertical_deg",
    "fluoro_s",
    "fluoro_first",
    "needle_path",
    "ideal_path",
    "ideal_landmarks",
    "verdict",
    "peak_axial_N",
    "punctures",
    "repunctures",
    "reentries",
    "device",
    "device_peak_force_N",
    "puncture_force_N",
    "bone_contact_s",
    "force_profile",
)


def save(app: App, v: dict) -> int | None:
    """Save the attempt through the Records resource (Settings class/trainee); raises UserError on failure.

    Returns None, storing nothing, when the Records refuse all saves (a replay): the attempt is then
    closed exactly as the recorded session closed it, so the replay reaches the same state.
    """
    if v["landmark_error_mm"] is None and app.resource(NeedleScene).landmark_score != "none":
        raise UserError("place all the landmarks before saving: the landmark error needs them")
    if app.resource(Records).refuses:
        return None
    s = app.resource(Settings)
    rec = attempt_record(app.resource(PackResource).pack.name, v)
    if isinstance(s.get("protocol"), dict):  # a study trial (chainsim protocol): which one, in its details
        rec["details"]["protocol"] = dict(s.get("protocol"))
    return app.resource(Records).save_attempt(
        s.get("class") or DEFAULT_CLASS,
        s.get("trainee") or DEFAULT_TRAINEE,
        rec,
    )


def my_attempts(app: App, limit: int = 6) -> list[str]:
    """Panel lines for the current trainee's saved attempts, newest last (the View of Fig. 3.11)."""
    s = app.resource(Settings)
    cls, who = s.get("class") or DEFAULT_CLASS, s.get("trainee") or DEFAULT_TRAINEE
    rows = app.resource(Records).list_attempts(cls, who)
    scene = app.get_resource(NeedleScene)
    lines = [f"Attempts of {who} ({cls}): {len(rows)}"]
    # numbered 1..N as the trainee made them (the save message uses the same numbers), the target named
    for k, r in enumerate(rows[-limit:], len(rows) - len(rows[-limit:]) + 1):
        ne = "-" if r["needle_error_mm"] is None else f"{r['needle_error_mm']:.1f} mm"
        reached = "nothing" if r["target"] in (None, "none") else (scene.label(r["target"]) if scene else r["target"])
        lines.append(
            f"{k}. {r['created_at'][:16].replace('T', ' ')}: {r['duration_s']:.1f} s, landmarks "
            f"{r['landmark_error_mm']:.1f} mm, needle {ne}, reached {reached}"
        )
    if rows:
        lines.append(f"Delete attempt (press twice) removes number {len(rows)}, the newest.")
    return lines


def own_count(app: App) -> int | None:
    """How many attempts the signed-in trainee has saved (the number My attempts gives the newest)."""
    try:
        return len(app.resource(Records).list_attempts(*_who(app)))
    except (UserError, OSError):
        return None


def _who(app: App) -> tuple[str, str]:
    s = app.resource(Settings)
    return s.get("class") or DEFAULT_CLASS, s.get("trainee") or DEFAULT_TRAINEE


def newest_own(app: App) -> int | None:
    """Id of the signed-in trainee's newest saved attempt, if any."""
    try:
        rows = app.resource(Records).list_attempts(*_who(app))
    except UserError:  # nothing saved yet under this class and name
        return None
    return rows[-1]["id"] if rows else None


def delete_own(app: App, attempt_id: int) -> None:
    """Delete one of the signed-in trainee's attempts (never someone else's)."""
    rec = app.resource(Records)
    if rec.delete_attempt is None:
        raise UserError("these records cannot be deleted from the trainer; ask your trainer")
    rec.delete_attempt(*_who(app), attempt_id)


def geometry(app: App, v: dict, trace: list) -> None:
    """Add to `v` what the debrief draws: the needle path (thinned), the ideal path and the ideal
    place of each placed landmark (the nearest point its D and d would call perfect)."""
    scene: NeedleScene = app.resource(NeedleScene)
    side = v["side"] or scene.sides[0]
    v["needle_path"] = db.thin(trace) if len(trace) else []
    npc = app.resource(PackResource).pack.section("needle_procedure")
    path = app.resource(PackResource).pack.section("paths").get(npc.get("ideal_path", "").format(side=side))
    v["ideal_path"] = (
        [[round(float(c), 2) for c in path["entry"]], [round(float(c), 2) for c in path["target"]]] if path else None
    )
    ideal = []
    for t, mark in zip(scene.landmark_targets[side], v["landmarks"], strict=False):
        p = None if mark is None else db.ideal_landmark(t.point, t.ideal_mm, t.plane, mark)
        ideal.append(None if p is None else [round(float(c), 2) for c in p])
    v["ideal_landmarks"] = ideal
    rows = vd.verdicts(app.resource(PackResource).pack.section("metrics"), v["metrics"])
    o = vd.outcome(rows)
    v["verdict"] = {"passed": o["passed"], "met": o["met"], "judged": o["judged"], "critical": o["critical"]}
    # a stored verdict says what it rested on: each benchmark, published, the programme's or provisional
    v["verdict"]["benchmarks"] = vd.rested_on(rows)


#: what `geometry` adds to the assessment values
GEOMETRY_KEYS = ("needle_path", "ideal_path", "ideal_landmarks", "verdict")


def debrief_rows(v: dict, scene: NeedleScene, pack) -> list[tuple[str, str]]:
    """The debrief as (text, tone) rows: the verdict, one row per metric with its benchmark, the
    landmark terms, the X-ray and aids, the advice for each failed metric and what the views show."""
    rows = vd.verdicts(pack.section("metrics"), v["metrics"])
    o = vd.outcome(rows)
    head = f"Debrief, attempt {v.get('attempt', 1)}" + (f" ({v['side']} side)" if v["side"] else "")
    out = [(f"{head}: {vd.verdict_line(o)}", db.CRITICAL if (o["critical"] or not o["passed"]) else db.HEAD)]
    for r in rows:
        text = f"{r['label']}: {r['shown']}"
        if r["passed"] is None:
            out.append((f"{text} (no benchmark)", db.PLAIN))
        else:
            word = "CRITICAL" if r["critical"] else "pass" if r["passed"] else "FAIL"
            basis = ", provisional" if r["basis"] == vd.PROVISIONAL else ""
            out.append((f"{text} - {word} ({r['threshold']}{basis})", db.PASS if r["passed"] else db.FAIL))
    if vd.basis_note(rows):
        out.append((vd.basis_note(rows), db.NOTE))
    n = len(scene.landmark_ids)
    if n and v.get("D1") is not None:
        ds = ", ".join(vd.number(v[f"D{k}"], "mm") for k in range(1, n + 1))
        dp = ", ".join(vd.number(v[f"d{k}"], "mm") for k in range(1, n + 1))
        out.append(
            (f"Landmarks 1-{n}: off the ideal distance (D) {ds}; off their planes (d) {dp}", db.NOTE),
        )
    on = [k.replace("_", " ") for k, x in v["aids"].items() if x]
    out.append(
        (
            f"X-ray: {v.get('xray_shots', 0)} images, {v.get('fluoro_s', 0.0):.1f} s live. "
            f"Aids used: {', '.join(on) if on else 'none'}",
            db.NOTE,
        )
    )
    for r in rows:
        if r["advice"]:
            out.append((f"{r['label']}: {r['advice']}", db.ADVICE))
    if v.get("ideal_path") or any(v.get("ideal_landmarks") or []):
        out.append(("Green: the ideal landmarks and path; orange: your needle's path (surgeon's view, X-ray)", db.NOTE))
    return out


DEBRIEF_GREEN = (0.25, 1.0, 0.45, 1.0)
DEBRIEF_ORANGE = (1.0, 0.55, 0.1, 1.0)
DEBRIEF_OFFSET = (1.0, 1.0, 1.0, 0.9)


class DebriefDrawing:
    """The ideal landmarks as entities in the 3-D views (made on first use, hidden when closed); the
    paths are drawn over the views from HudState.debrief_paths (inside the head, bone would hide them)."""

    def __init__(self) -> None:
        self.marks: list[int] = []
        self.offsets: list[int] = []

    def show(self, v: dict | None) -> None:
        ideal = (v or {}).get("ideal_landmarks") or []
        while len(self.marks) < len(ideal):
            self.marks.append(esper.create_entity(Transform(), Marker(radius=1.3, color=np.array(DEBRIEF_GREEN))))
            self.offsets.append(esper.create_entity(PolyLine(color=DEBRIEF_OFFSET, visible=False, layer="debrief")))
        lines = []
        for k, (mark, off) in enumerate(zip(self.marks, self.offsets, strict=True)):
            p = ideal[k] if v is not None and k < len(ideal) else None
            m = esper.component_for_entity(mark, Marker)
            m.visible = p is not None
            if p is not None:
                esper.component_for_entity(mark, Transform).position = np.asarray(p, float)
            lines.append((off, None if p is None or v is None else [v["landmarks"][k], p]))
        for ent, pts in lines:
            pl = esper.component_for_entity(ent, PolyLine)
            pl.visible = pts is not None and len(pts) >= 2
            if pl.visible:
                pl.points = np.asarray(pts, float).reshape(-1, 3)

    def paths(self, v: dict) -> list[tuple]:
        """The lines drawn over the last X-ray image: (points (K, 3), RGBA)."""
        out = []
        if v.get("ideal_path"):
            out.append((np.asarray(v["ideal_path"], float), DEBRIEF_GREEN))
        if len(v.get("needle_path") or []) >= 2:
            out.append((np.asarray(v["needle_path"], float), DEBRIEF_ORANGE))
        return out


class AssessmentSystem:
    def __init__(self, app: App):
        self.widgets = app.events.reader(Widget)
        self.errors: list[str] = []
        self.delete_armed: int | None = None  # the attempt a first Delete press chose
        self.panel_shown: list[str] | None = None  # the self-assessment lines on the panel, while they are
        self.trace = db.PathTrace()
        self.drawing = DebriefDrawing()
        self.drawn_path = 0  # points of the needle path the debrief drawing shows
        # ((figures, path, its length), geometry, debrief rows or None) of the last frame, and whether
        # this frame's figures were that frame's (see `values`)
        self.memo: tuple | None = None
        self.memo_hit = False
        info = app.get_resource(RunInfo)
        self.replay = bool(info is not None and info.replay)  # window-only work skipped (RunInfo.replay)

    def open_debrief(self, app: App, v: dict) -> None:
        h = hud(app)
        scene, pack = app.resource(NeedleScene), app.resource(PackResource).pack
        h.debrief = debrief_rows(v, scene, pack)
        h.debrief_paths = self.drawing.paths(v)
        # a device's force profile (time, depth, force, events): drawn against depth over the debrief
        h.debrief_force = [(p[1], p[2], p[3]) for p in v.get("force_profile") or []]
        self.drawn_path = len(v["needle_path"])
        self.drawing.show(v)
        # the panel keeps the headline; the whole debrief is over the surgeon's view
        o = v["verdict"]
        h.panel_text = [
            panel_lines(v, scene, pack)[0],
            ("FAILED (critical error)" if o["critical"] else "PASSED" if o["passed"] else "FAILED")
            + ": the debrief is over the surgeon's view until Reset (r) or My attempts",
        ]
        self.panel_shown = list(h.panel_text)

    def close_debrief(self, app: App) -> None:
        h = hud(app)
        h.debrief, h.debrief_paths, h.debrief_force = [], [], []
        self.drawing.show(None)

    def values(self, app: App) -> dict:
        """The assessment values now: the attempt's figures and what the debrief draws.

        The debrief's geometry and rows are functions of the figures and the needle's path alone, so
        a frame whose figures and path are those of the frame before (the debrief shown while the
        trainee reads it) takes them from that frame instead of working them out again."""
        v = compute(app)
        # the landmarks by repr too: == takes -0.0 for 0.0, and an ideal landmark keeps the sign of a zero
        key = (dict(v), repr(v["landmarks"]), self.trace.points, len(self.trace.points))
        last = self.memo
        if last is not None and last[0][2] is key[2] and last[0][1:] == key[1:] and last[0][0] == key[0]:
            v.update(last[1])
            self.memo_hit = True
            return v
        geometry(app, v, self.trace.points)
        self.memo = (key, {k: v[k] for k in GEOMETRY_KEYS}, None)
        self.memo_hit = False
        return v

    def rows(self, app: App, v: dict) -> list[tuple[str, str]]:
        """debrief_rows of `v`, those of the last frame when `values` found its figures unchanged."""
        memo = self.memo
        if self.memo_hit and memo is not None and memo[2] is not None:
            return memo[2]
        rows = debrief_rows(v, app.resource(NeedleScene), app.resource(PackResource).pack)
        if memo is not None:
            self.memo = (memo[0], memo[1], rows)
        return rows

    def with_saves(self, app: App, v: dict) -> dict:
        """`v` with the ids this session's saves got and the errors of those that failed."""
        ps = esper.component_for_entity(app.resource(NeedleHandles).procedure, ProcedureState)
        v["saved"] = list(ps.saved)
        v["save_errors"] = list(self.errors)
        return v

    def deferred(self, app: App):
        """The values of this frame's end, worked out when they are read (Assessment.defer)."""

        def later() -> dict:
            with app.active():
                return self.with_saves(app, self.values(app))

        return later

    def __call__(self, app: App) -> None:

        handles: NeedleHandles = app.resource(NeedleHandles)
        ps0 = esper.component_for_entity(handles.procedure, ProcedureState)
        st0: NeedleState = esper.component_for_entity(handles.needle, NeedleState)
        inserted = st0.placed and st0.depth > 0
        self.trace.update(ps0.attempt, st0.tip() if inserted else None, inserted)
        events = self.widgets.read()
        if self.replay and not events and self.panel_shown is None:
            # no press to act on and no debrief to follow: nothing this frame reads the values, so a
            # replay works them out only when they are read, from the state this frame leaves
            app.resource(Assessment).defer(self.deferred(app))
            return
        v = self.values(app)
        for ev in events:
            h = hud(app)
            if ev.name == "self_assessment":
                self.open_debrief(app, v)
            elif ev.name == "save" and ps0.closed:
                # a second press (a double click, a script that saves after a tool pressed Save) must not
                # store the same attempt twice
                h.message(f"Attempt {ps0.attempt} is already saved. Reset (r) to try again.")
            elif ev.name == "save":
                try:
                    rid = save(app, v)
                except SavedLocally as e:  # safe on this computer; the records server gets it later
                    h.message(f"Saved on this computer: {e}", 8.0)
                    esper.component_for_entity(app.resource(NeedleHandles).procedure, ProcedureState).closed = True
                except (UserError, OSError) as e:  # a full disk or a vanished folder must not end the session
                    h.message(f"Not saved: {e}", 8.0)
                    self.errors.append(str(e))
                    failed = app.get_resource(FailedSaves)
                    if failed is not None:  # a headless run then ends with exit 2
                        failed.messages.append(str(e))
                else:
                    ps = esper.component_for_entity(app.resource(NeedleHandles).procedure, ProcedureState)
                    ps.closed = True  # this attempt is done; the next action begins another
                    self.open_debrief(app, v)  # a saved attempt ends with its debrief
                    s = app.resource(Settings)
                    # in a study the session moves on by itself: no Reset to suggest
                    again = "" if s.get("protocol") else " Reset (r) to try again."
                    if rid is None:
                        h.message(f"Not saved: {app.resource(Records).refuses}.{again}")
                    else:
                        ps.saved.append(rid)
                        # a records server files the attempt under the signed-in account, not the typed names
                        filed = app.resource(Records).filed_as
                        cls, who, n = (filed and filed(rid)) or (*_who(app), own_count(app))
                        h.message(
                            f"Attempt {ps.attempt} saved for {who} in class {cls}"
                            + (f" (number {n} in My attempts)" if n else "")
                            + f".{again}"
                        )
            elif ev.name == "delete_attempt":
                self.delete(app, h)
            elif ev.name == "my_attempts":
                try:
                    h.panel_text = my_attempts(app)
                except (UserError, OSError):  # nothing saved yet under this class and name
                    s = app.resource(Settings)
                    h.panel_text = [
                        f"No saved attempts yet for {s.get('trainee') or DEFAULT_TRAINEE} "
                        f"in class {s.get('class') or DEFAULT_CLASS}."
                    ]
            if ev.name != "delete_attempt":
                self.delete_armed = None
        h = hud(app)
        if self.panel_shown is not None:
            if h.panel_text != self.panel_shown:  # something else took the panel (My attempts, a new attempt)
                self.panel_shown = None
                self.close_debrief(app)
            elif self.rows(app, v) != h.debrief or len(v["needle_path"]) != self.drawn_path:
                # the debrief follows the attempt while it is shown (a bone hit's needle error)
                self.open_debrief(app, v)
        app.resource(Assessment).values = self.with_saves(app, v)

    def delete(self, app: App, h) -> None:
        """Delete the trainee's newest attempt: the first press names it, the second deletes it."""

        try:
            newest = newest_own(app)
            if newest is None:
                h.message("You have no saved attempts to delete.")
            elif self.delete_armed != newest:
                self.delete_armed = newest
                h.message(f"Press Delete attempt again to delete your attempt {newest}.", 6.0)
            else:
                delete_own(app, newest)
                self.delete_armed = None
                h.message(f"Attempt {newest} deleted.")
                h.panel_text = my_attempts(app)
        except (UserError, OSError) as e:
            h.message(f"Not deleted: {e}", 8.0)


def plugin(app: App) -> None:

    if not app.has_resource(Assessment):
        app.insert_resource(Assessment())
    system = AssessmentSystem(app)
    app.add_system("procedure", system, order=ORDER_ASSESSMENT, name="needle_assessment")

    def settle() -> None:  # values a replay deferred are worked out while its world is still there
        _ = app.resource(Assessment).values

    app.on_close(settle)

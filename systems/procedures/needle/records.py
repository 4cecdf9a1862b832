"""The needle procedure's attempt in the trainee records and the thesis study: field names, aids and words.

Before the records kept procedure-neutral metrics (schema version 6), an attempt was a needle attempt:
fixed columns of the attempts table (schema versions 1-5) hold its time, the two errors of thesis
6.1.5, what the tip ended on, bone contacts, path, redirections and the X-ray's cost, and every stored
file keeps them. The shell (the records store and its validation, reports, exports, the server's pages,
the study screens) takes those fields' names, units and words from LAYOUT, through the procedure's
declaration (chainsim.systems.procedures.needle.declaration), so the procedure's vocabulary
stays in its folder; what a pack declares in [metrics.NAME] (label, units, benchmark) is said as
declared.

The thesis study (6.1.2-6.1.5: its tasks, how each is scored, the features its participants rated) is
this procedure's too (STUDY); `chainsim protocol` and the window's study screens read it from there.
"""

from __future__ import annotations

from chainsim.systems.procedures.procedure import AttemptLayout, Column, Study

#: the error of the points the trainee marks (thesis 6.1.5's E over the three marks), in mm
MARK_ERROR = "landmark_error_mm"
#: the tip's distance to the target's centre minus its radius at the last contact (6.1.5), in mm;
#: negative inside the opening, None when the needle touched nothing
TARGET_ERROR = "needle_error_mm"
#: contacts with bone
BONE_CONTACTS = "skull_contacts"

#: the attempts table's fixed metric columns, in the order of the schema versions that added them
COLUMNS: tuple[Column, ...] = (
    Column("duration_s", "Time", "s", "time_s"),
    Column(MARK_ERROR, "Landmark error", "mm", "landmark_mm"),
    Column(TARGET_ERROR, "Needle error", "mm", "needle_mm"),
    Column(BONE_CONTACTS, "Bone contacts", "", "contacts", whole=True),
    Column("path_length_mm", "Insertion path length", "mm", "path_mm"),
    Column("redirections", "Redirections", "", "redirect", whole=True),
    Column("xray_shots", "X-ray images", "", "xrays", whole=True),
    Column("exposure_s", "X-ray exposure", "s", "exposure_s"),
    Column("dose_mgy", "Estimated skin dose", "mGy", "dose_mgy"),
)

#: the aids of thesis 3.3.4 / 6.1.3 whose effect the study compares, as an attempt records them
AIDS = ("skin_transparent", "reference_planes", "landmark_planes", "tip_view", "collision_signals")


def contact_facts(details: dict) -> list[tuple[str, str]]:
    """An attempt's page says what the needle touched: (words, value) lines from the assessment's
    `contacts`, which holds every role touched, the target's too. Only the obstacles' (bone) contacts
    are counted (BONE_CONTACTS); reaching the target is said as such. The target's role is the one
    whose ROLE_radius_mm the assessment keeps; without it (an attempt saved before) the roles are
    listed as they were stored."""
    contacts = dict(details.get("contacts") or {})
    target = next((k.removesuffix("_radius_mm") for k in details if k.endswith("_radius_mm")), None)
    if target is None:
        return [("Contacts", "; ".join(f"{k.replace('_', ' ')} {v}" for k, v in contacts.items()))] if contacts else []
    reached = bool(contacts.pop(target, 0))
    out = []
    if contacts:
        out.append(("Bone contacts, per bone", "; ".join(f"{k.replace('_', ' ')} {v}" for k, v in contacts.items())))
    words = f"Needle reached the {target.replace('_', ' ')}"
    out.append((words, "yes (not a contact: only bone contacts are counted)" if reached else "no"))
    return out


#: what the tip may end on that is not a target: nothing, or bone (an attempt so ended did not succeed)
KNOWN_TARGETS = frozenset({"none", "skull", "mandible"})
#: what an attempt's target looks like beside the known ones, for the message refusing a malformed one
TARGET_FORM = "foramen_ovale_<side>"

#: details keys: the points the trainee marked and their ideal positions (x, y, z mm; None: not placed)
MARKS = "landmarks"
IDEAL_MARKS = "ideal_landmarks"
#: the attempt page's table of the marked points: its heading, the column naming a point, and what the
#: terms D and d per point are (HTML, this module's own text)
MARKS_HEADING = "Landmarks"
MARKS_COLUMN = "landmark"
MARKS_NOTE = (
    "For landmark k, D<sub>k</sub> (D1, D2, D3) is how far its distance to its anatomical point is from the "
    "ideal distance, and d<sub>k</sub> (d1, d2, d3) is its distance to the landmark's plane (thesis 6.1.5); "
    "0 mm is a perfect landmark. The landmark error is the mean of every D and d."
)

#: details and assessment fields said in words on an attempt's page: field -> (words, units)
FIELD_WORDS: dict[str, tuple[str, str]] = {
    "target": ("Reached", ""),
    **{c.name: (c.words, c.units) for c in COLUMNS},
    "side": ("Side", ""),
    "needle_dist_mm": ("Tip to the target's centre at the last contact", "mm"),
    "first_contact_dist_mm": ("Tip to the target's centre at the first contact", "mm"),
    "rotation_refused": ("Refused rotations", ""),
    "rotation_horizontal_deg": ("Horizontal turn", "deg"),
    "rotation_vertical_deg": ("Vertical tilt", "deg"),
    "fluoro_s": ("Live fluoroscopy", "s"),
    "hit_point": ("Last contact point", "mm"),
}

# -- the thesis study (6.1.2-6.1.5) -----------------------------------------------------------------

#: the study's tasks, each scored by one attempt field
TASK_METRIC = {"location": MARK_ERROR, "insertion": TARGET_ERROR}
#: how each task is scored, in words
TASK_SCORED = {"location": "landmark error", "insertion": "needle error E = Dist - R"}
#: what a participant does in a trial of each task (the page before the trial)
TASK_DOES = {
    "location": "Place the three landmarks on the face (1 beside the mouth, 2 at the pupil, 3 in front of the "
    "ear), then press **Save attempt**.",
    "insertion": "The landmarks are placed for you. Aim the needle with the two dials and insert it into the "
    "foramen ovale, then press **Save attempt**.",
}
#: an insertion trial starts from the marks at their ideal points: the [points] of mark k on a side
IDEAL_POINT = "landmark{k}_ideal_{side}"
MARK_COUNT = 3

#: the post-session ratings (id, question); ids match the thesis's reported averages where it has one
RATINGS: tuple[tuple[str, str], ...] = (
    ("pages_understandable", "The help pages are easy to understand"),
    ("interface_easy", "The window and its controls are easy to learn and use"),
    ("graphics_understandable", "The 3-D graphics are easy to understand"),
    ("reference_planes", "Reference planes: useful for marking the landmarks"),
    ("landmark_planes", "Planes through landmarks: useful for rotation and insertion"),
    ("local_viewer", "Needle-tip view: useful for rotation and insertion"),
    ("signals", "Collision lights: useful for insertion"),
    ("transparent_skin", "Transparent skin: useful for understanding the 3-D anatomy"),
    ("carm_view", "C-arm (X-ray) view: useful for finding the foramen"),
)
#: post-session averages the thesis reports (6.1.5), on the same 1-10 scale
THESIS_RATINGS = {"reference_planes": 9.5, "local_viewer": 9.7, "landmark_planes": 8.8, "signals": 9.3}

#: the needle attempt as the records and their pages read it
LAYOUT = AttemptLayout(
    columns=COLUMNS,
    aids=AIDS,
    mark_error=MARK_ERROR,
    target_error=TARGET_ERROR,
    known_targets=KNOWN_TARGETS,
    target_form=TARGET_FORM,
    marks=MARKS,
    ideal_marks=IDEAL_MARKS,
    marks_heading=MARKS_HEADING,
    marks_column=MARKS_COLUMN,
    marks_note=MARKS_NOTE,
    field_words=FIELD_WORDS,
    contact_facts=contact_facts,
)

#: the thesis study (6.1.2-6.1.5)
STUDY = Study(
    task_metric=TASK_METRIC,
    task_scored=TASK_SCORED,
    task_does=TASK_DOES,
    ideal_point=IDEAL_POINT,
    mark_count=MARK_COUNT,
    ratings=RATINGS,
    published_ratings=THESIS_RATINGS,
)

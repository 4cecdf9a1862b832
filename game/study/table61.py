"""A study's results over every participant in the records: Table 6.1 and the questionnaire ratings.

Thesis 6.1.4-6.1.5 report the mean error per task and condition over all participants (Table 6.1:
location with and without reference planes, rotation and insertion with the needle-tip view and
without any clue) and the average post-session rating of each feature. Attempts made in a study
carry `details.protocol` = {"study", "participant", "trial", "task", "condition", "order", ...}
(written by `chainsim protocol`), questionnaires carry the study as their session; this module
groups them. Each task is scored by one attempt field, as the needle procedure's study declares it
(chainsim.systems.procedures.records_study(): location by the error of the marked points, rotation
and insertion by the needle error E = Dist - R, 6.1.5); an attempt whose needle touched nothing has
no needle error and is counted but not scored.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from chainsim.systems.procedures import records_study

#: the study the records hold the trials of
STUDY = records_study()

TASKS = ("location", "insertion")
TASK_TITLE = {"location": "Location", "insertion": "Rotation and insertion"}
TASK_METRIC = STUDY.task_metric
#: thesis Table 6.1, mean error in cm, converted to mm
THESIS_MM = {
    ("location", "reference_planes"): 3.2,
    ("location", "without_clues"): 4.7,
    ("insertion", "local_viewer"): 32.0,
    ("insertion", "without_clues"): 44.0,
}


def study_rows(attempts: Iterable[dict[str, Any]], study: str, practice: bool = False) -> list[dict[str, Any]]:
    """One row per attempt of `study`: participant, task, condition, the task's error (or None). Practice
    trials are left out (they are never scored) unless ``practice``."""
    out = []
    for a in attempts:
        p = (a.get("details") or {}).get("protocol") or {}
        if p.get("study") != study or p.get("task") not in TASKS or (p.get("practice") and not practice):
            continue
        out.append(
            {
                "participant": p.get("participant") or a.get("trainee"),
                "task": p["task"],
                "condition": p.get("condition", ""),
                "error_mm": a.get(TASK_METRIC[p["task"]]),
                "attempt_id": a.get("id"),
                "scripted": bool(p.get("scripted", False)),
            }
        )
    return out


def design_notes(attempts: Iterable[dict[str, Any]], study: str) -> list[str]:
    """What a methods reviewer should know about `study`'s trials besides the table: practice trials left
    out, and trials whose condition order came from one machine's register instead of the study's sequence."""
    practice = local = 0
    for a in attempts:
        p = (a.get("details") or {}).get("protocol") or {}
        if p.get("study") != study or p.get("scripted"):
            continue
        practice += bool(p.get("practice"))
        local += bool((p.get("allocation") or {}).get("warning"))
    out = []
    if practice:
        out.append(f"{practice} practice trial(s) left out of the table")
    if local:
        out.append(
            f"{local} trial(s) took their condition order from one machine's own register, not the records "
            "server's sequence: another machine may have given the same order"
        )
    return out


def table(rows: Iterable[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    """(task, condition) -> mean error over the scored attempts, attempts scored / made, participants."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((r["task"], r["condition"]), []).append(r)
    out = {}
    for key, rs in groups.items():
        used = [r["error_mm"] for r in rs if r["error_mm"] is not None]
        out[key] = {
            "mean_error_mm": sum(used) / len(used) if used else None,
            "scored": len(used),
            "attempts": len(rs),
            "participants": len({r["participant"] for r in rs}),
            "thesis_mm": THESIS_MM.get(key),
        }
    return out


def format_table(tab: dict[tuple[str, str], dict[str, Any]], label: str) -> str:
    """Table 6.1's shape: tasks across, conditions under them; this study's means beside the thesis's."""
    cols = [(t, c) for task in TASKS for (t, c) in tab if t == task]
    width = 18
    head1 = " " * 28
    head2 = " " * 28
    for task in TASKS:
        n = sum(1 for t, _ in cols if t == task)
        if n:
            head1 += TASK_TITLE[task].center(width * n)
    for _t, c in cols:
        head2 += c.replace("_", " ").center(width)
    row = f"{('Mean error, ' + label + ' (mm)')[:27]:28}"
    count = f"{'  attempts scored / made':28}"
    people = f"{'  participants':28}"
    thesis = f"{'Thesis Table 6.1 (mm)':28}"
    for key in cols:
        v = tab[key]
        row += (f"{v['mean_error_mm']:.2f}" if v["mean_error_mm"] is not None else "-").center(width)
        count += f"{v['scored']}/{v['attempts']}".center(width)
        people += str(v["participants"]).center(width)
        thesis += (f"{v['thesis_mm']:.1f}" if v["thesis_mm"] is not None else "-").center(width)
    return "\n".join(
        [
            f"Performance test results (after thesis Table 6.1; location: {STUDY.task_scored['location']}, "
            f"rotation and insertion: {STUDY.task_scored['insertion']})",
            head1.rstrip(),
            head2.rstrip(),
            row.rstrip(),
            count.rstrip(),
            people.rstrip(),
            thesis.rstrip(),
        ]
    )


def ratings(questionnaires: Iterable[dict[str, Any]], study: str) -> dict[str, dict[str, Any]]:
    """Post-session questionnaire of `study`: question id -> mean rating and how many answered."""
    sums: dict[str, list[float]] = {}
    for q in questionnaires:
        if q.get("kind") != "post" or q.get("session") != study:
            continue
        for k, v in (q.get("answers") or {}).items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                sums.setdefault(k, []).append(float(v))
    return {k: {"mean": sum(v) / len(v), "answers": len(v)} for k, v in sums.items()}


def format_ratings(rates: dict[str, dict[str, Any]], labels: dict[str, str], thesis: dict[str, float]) -> str:
    """The mean post-session ratings as text, in the order of `labels` (then any others)."""
    if not rates:
        return "Post-session ratings: none yet"
    lines = ["Post-session ratings (1 = poor, 10 = very good)", f"{'':58}{'mean':>6}{'n':>4}{'thesis':>8}"]
    keys = [k for k in labels if k in rates] + [k for k in rates if k not in labels]
    for k in keys:
        v = rates[k]
        th = thesis.get(k)
        lines.append(f"{labels.get(k, k)[:57]:58}{v['mean']:6.1f}{v['answers']:4d}{(f'{th:.1f}' if th else '-'):>8}")
    return "\n".join(lines)


def markdown_table(tab: dict[tuple[str, str], dict[str, Any]]) -> str:
    """Table 6.1 as a Markdown table for the window's page box: one row per task and condition."""
    rows = [
        "| Task | Condition | Mean error, mm | Scored | People | Thesis, mm |",
        "|---|---|---|---|---|---|",
    ]
    for task in TASKS:
        for (t, c), v in tab.items():
            if t != task:
                continue
            mean = f"{v['mean_error_mm']:.2f}" if v["mean_error_mm"] is not None else "-"
            th = f"{v['thesis_mm']:.1f}" if v["thesis_mm"] is not None else "-"
            rows.append(
                f"| {TASK_TITLE[t]} | {c.replace('_', ' ')} | {mean} | {v['scored']}/{v['attempts']} | "
                f"{v['participants']} | {th} |"
            )
    return "\n".join(rows)


def markdown_ratings(rates: dict[str, dict[str, Any]], labels: dict[str, str], thesis: dict[str, float]) -> str:
    """The mean post-session ratings as a Markdown table, in the order of `labels`."""
    rows = ["| Feature | Mean | n | Thesis |", "|---|---|---|---|"]
    for k, label in labels.items():
        if k in rates:
            th = thesis.get(k)
            rows.append(f"| {label} | {rates[k]['mean']:.1f} | {rates[k]['answers']} | {f'{th:.1f}' if th else '-'} |")
    return "\n".join(rows) if len(rows) > 2 else "No ratings yet."

"""A study protocol and its trials, as the simulator runs them and the records server checks them.

A protocol (``chainsim protocol PROTOCOL.toml``) names a pack and its trials: each a condition of a
task with the aids set as the condition says. A participant takes the trials in the order of their
slot in the study's register (chainsim.game.study.register): per task its practice trials, then
cycles of its conditions, each cycle in the row of a balanced Latin square the slot picks (``plan``).

The study's design (the trials and their aids, without the scripts of a scripted run) is filed on the
records server before its first participant (``design``, kept by ``chainsim.game.study.register``),
so the server knows, for every participant it registered, which trial comes at which place of their
session and with which aids. A trial uploaded from the window or saved in the browser trainer carries
``details.protocol`` (study, participant, trial, condition, practice, order, slot); ``check_claim``
answers it with the trial the server's own design and register give that place, or refuses it in one
line when the two disagree. The events a study session sets itself - the trial's aids, a fresh attempt
and, for an insertion trial, the points marked for the participant (``session_events``) - are not the
participant's input, and ``check_session_events`` accepts them in a trial's recording as the
protocol's, and nothing else of their kind.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from chainsim.components.input_events import PickPoint, Widget
from chainsim.systems.engine import datafile, limits
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures import records_layout, records_study
from chainsim.systems.view.ui.widgets import WidgetState

#: the attempt as the records keep it (the fixed columns' procedure, chainsim.systems.procedures)
LAYOUT = records_layout()
#: the study the records hold the trials of
STUDY = records_study()

AIDS = LAYOUT.aids
TASKS = ("location", "insertion")
TOP_KEYS = {"format", "pack", "title", "description", "trial", "require_witnessed", "practice"}
TRIAL_KEYS = {"name", "task", "condition", "scripts", "script", "repeat", "steps", "aids"}
#: how a participant's slot picks their condition order (``plan``)
DESIGN = "balanced Latin square"
#: what the design filed on a records server keeps of each trial (the scripts are a scripted run's only)
DESIGN_TRIAL_KEYS = ("name", "task", "condition", "repeat", "aids")
#: the kinds of event a study session sets itself (not window input), checked by ``check_session_events``
SESSION_KINDS = ("widget", "pick")
#: the widget that starts a fresh attempt (marked points cleared) at each trial's start
RESET = "reset"
#: the task whose trials start from points marked for the participant at their ideal places
MARKED_TASK = "insertion"
#: seconds from a trial's start to its fresh attempt, and to the lock of its aids (the page's Enter counts
#: as the start; the aids' events come first, at 0.01 s)
RESET_AFTER_S, LOCK_AFTER_S = 0.05, 0.2
#: how far (mm) a point the session marked may lie from the pack's ideal point (JSON keeps 17 digits)
POINT_TOLERANCE = 1e-6


def _err(where: str, msg: str) -> UserError:
    return UserError(f"{where}: {msg}")


def load_protocol(path: str | Path) -> dict:
    """Read and check a protocol; every problem is a one-line UserError naming the key."""
    path = Path(path)
    data = datafile.parse_toml(
        datafile.read_text(path, max_bytes=limits.MAX_SCRIPT_BYTES, what="protocol file"), str(path)
    )
    where = str(path)
    extra = sorted(set(data) - TOP_KEYS)
    if extra:
        raise _err(where, f"unknown key '{extra[0]}'; expected {', '.join(sorted(TOP_KEYS))}")
    if data.get("format") != 1:
        raise _err(where, f"'format' must be 1, got {data.get('format')!r}")
    if not isinstance(data.get("pack"), str) or not data["pack"]:
        raise _err(where, "'pack' must name a pack (e.g. \"prp\")")
    trials = data.get("trial")
    if not isinstance(trials, list) or not trials:
        raise _err(where, "needs at least one [[trial]]")
    out: list[dict] = []
    names: set[str] = set()
    for i, t in enumerate(trials, 1):
        out.append(_trial(t, f"{where}: trial {i}", f"trial-{i}", names))
    practice = _practice(data.get("practice", 0), where)
    runs = sum(max(len(t["scripts"]), 1) * t["repeat"] for t in out)
    if runs > limits.MAX_PROTOCOL_RUNS:
        raise _err(where, f"asks for {runs:,} runs, over the {limits.MAX_PROTOCOL_RUNS:,} limit (docs/limits.md)")
    return {
        "path": path,
        "pack": data["pack"],
        "title": data.get("title", ""),
        "trials": out,
        "practice": practice,
        # the summary counts only attempts the records server witnessed (made in its browser trainer)
        "require_witnessed": _flag(data, "require_witnessed", where),
    }


def _practice(value: object, where: str) -> int:
    try:
        # practice trials per task, before its scored ones: saved marked practice, never counted
        return limits.whole(value, 0, limits.MAX_REPEAT)
    except limits.LimitError as e:
        raise _err(where, f"'practice' {e} (docs/limits.md)") from None


def _trial(t: object, w: str, default_name: str, names: set[str]) -> dict:
    """One [[trial]] of a protocol, checked (``names``: the trial names so far, this one added)."""
    if not isinstance(t, dict):
        raise _err(w, "must be a table")
    extra = sorted(set(t) - TRIAL_KEYS)
    if extra:
        raise _err(w, f"unknown key '{extra[0]}'; expected {', '.join(sorted(TRIAL_KEYS))}")
    name = t.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise _err(w, "'name' must be text")
    if name in names:
        raise _err(w, f"duplicate trial name '{name}'")
    names.add(name)
    task = t.get("task")
    if task not in TASKS:
        raise _err(w, f"'task' must be one of {', '.join(TASKS)}, got {task!r}")
    cond = t.get("condition")
    if not isinstance(cond, str) or not cond:
        raise _err(w, "'condition' must be text (the table column, e.g. \"without_clues\")")
    if "script" in t and "scripts" in t:
        raise _err(w, "give 'script' or 'scripts', not both")
    scripts = t.get("scripts", [t["script"]] if "script" in t else [])
    if not isinstance(scripts, list) or not all(isinstance(s, str) and s for s in scripts):
        raise _err(w, "'scripts' must be an array of script paths")
    try:
        repeat = limits.whole(t.get("repeat", 1), 1, limits.MAX_REPEAT)
    except limits.LimitError as e:
        raise _err(w, f"'repeat' {e} (docs/limits.md)") from None
    steps = t.get("steps")
    if steps is not None:
        try:
            steps = limits.whole(steps, 1, limits.MAX_STEPS)
        except limits.LimitError as e:
            raise _err(w, f"'steps' {e} (docs/limits.md)") from None
    aids = t.get("aids", {})
    if not isinstance(aids, dict):
        raise _err(w, "'aids' must be a table of true/false")
    for k, v in aids.items():
        if k not in AIDS:
            raise _err(w, f"unknown aid '{k}'; aids are {', '.join(AIDS)}")
        if not isinstance(v, bool):
            raise _err(w, f"aid '{k}' must be true or false, got {v!r}")
    return {
        "name": name,
        "task": task,
        "condition": cond,
        "scripts": scripts,
        "repeat": repeat,
        "steps": steps,
        "aids": {a: bool(aids.get(a, False)) for a in AIDS},
    }


def _flag(data: dict, key: str, where: str) -> bool:
    value = data.get(key, False)
    if not isinstance(value, bool):
        raise _err(where, f"'{key}' must be true or false, got {value!r}")
    return value


def study_name(proto: dict) -> str:
    """The study's label in the records: the protocol file's name without .toml."""
    return proto["path"].stem


def latin_row(n: int, participant: int) -> list[int]:
    """Order of n conditions for a participant: a row of a balanced Latin square (each condition comes
    first equally often and follows each other condition equally often over n participants; for an odd n,
    over 2n, the second n taking the rows reversed)."""
    first = [j // 2 if j % 2 == 0 else n - (j + 1) // 2 for j in range(n)]
    row = [(v + participant) % n for v in first]
    if n % 2 == 1 and (participant // n) % 2 == 1:
        row.reverse()
    return row


def plan(proto: dict, participant: int) -> list[dict]:
    """The participant's trials in order: per task (in protocol order), its practice trials (the conditions
    in the participant's order, round again if there are more), then cycles of its conditions."""
    out = []
    tasks = []
    for t in proto["trials"]:
        if t["task"] not in tasks:
            tasks.append(t["task"])
    for task in tasks:
        trials = [t for t in proto["trials"] if t["task"] == task]
        order = latin_row(len(trials), participant)
        for k in range(proto.get("practice", 0)):
            out.append({**trials[order[k % len(order)]], "cycle": 0, "practice": True})
        for cycle in range(max(t["repeat"] for t in trials)):
            for i in order:
                if cycle < trials[i]["repeat"]:
                    out.append({**trials[i], "cycle": cycle + 1, "practice": False})
    for k, t in enumerate(out, 1):
        t["order"] = k
    return out


# -- the design a records server keeps -----------------------------------------------------------


def design(proto: dict) -> dict:
    """What a records server keeps of a protocol to check its trials: the pack, practice and the trials."""
    trials = [{k: t[k] for k in DESIGN_TRIAL_KEYS} for t in proto["trials"]]
    return {"pack": proto["pack"], "practice": proto.get("practice", 0), "trials": trials}


def clean_design(value: Any, study: str) -> dict:
    """A design sent to the records server, checked as a protocol file is; UserError naming what is wrong."""
    where = f"design of study {study!r}"
    if not isinstance(value, dict) or set(value) != {"pack", "practice", "trials"}:
        raise _err(where, "must be an object with pack, practice and trials (chainsim protocol sends it)")
    if not isinstance(value["pack"], str) or not value["pack"]:
        raise _err(where, "'pack' must name a pack")
    trials = value["trials"]
    if not isinstance(trials, list) or not 1 <= len(trials) <= limits.MAX_PROTOCOL_RUNS:
        raise _err(where, f"'trials' must be a list of 1 to {limits.MAX_PROTOCOL_RUNS} trials")
    names: set[str] = set()
    out = []
    for i, t in enumerate(trials, 1):
        if isinstance(t, dict) and set(t) - set(DESIGN_TRIAL_KEYS):
            raise _err(f"{where}: trial {i}", f"unknown key '{sorted(set(t) - set(DESIGN_TRIAL_KEYS))[0]}'")
        checked = _trial(t, f"{where}: trial {i}", f"trial-{i}", names)
        out.append({k: checked[k] for k in DESIGN_TRIAL_KEYS})
    return {"pack": value["pack"], "practice": _practice(value["practice"], where), "trials": out}


def design_text(value: dict) -> str:
    """A design as the text a database keeps (keys sorted: two sends of one design are the same text)."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"))


def check_claim(claim: Any, trial_design: dict | None, entry: dict | None, where: tuple[str, str]) -> dict:
    """The trial the records server's design and register give the place an upload claims, as the
    ``details.protocol`` it keeps; UserError (one line) when the upload's trial, condition, practice
    flag, slot or aids are not that trial's.

    ``claim``: the upload's ``details.protocol`` with its ``aids``; ``entry``: the participant's register
    entry (None: not registered); ``where``: the (class, trainee) the upload is filed under."""
    if not isinstance(claim, dict):
        raise UserError("details.protocol must be an object (study, participant, trial, order, ...)")
    study, code = claim.get("study"), claim.get("participant")
    if trial_design is None:
        raise UserError(
            f"study {study!r} has no design on this server: file it with chainsim protocol PROTOCOL.toml "
            "--register CODE ... --records URL before its trials are uploaded"
        )
    if entry is None or entry["class_name"] != where[0] or code != where[1]:
        raise UserError(
            f"participant {code!r} of this trial is not in the register of study {study!r} under class "
            f"{where[0]!r} and trainee {where[1]!r}; register them before their first trial"
        )
    trials = plan(trial_design, entry["slot"])
    order = claim.get("order")
    if isinstance(order, bool) or not isinstance(order, int) or not 1 <= order <= len(trials):
        raise UserError(f"details.protocol.order is {order!r}; expected a trial number from 1 to {len(trials)}")
    t = trials[order - 1]
    said = {"trial": claim.get("trial"), "condition": claim.get("condition"), "practice": bool(claim.get("practice"))}
    said["slot"] = (claim.get("allocation") or {}).get("slot")
    said["aids"] = {a: bool((claim.get("aids") or {}).get(a, False)) for a in AIDS}
    given = {"trial": t["name"], "condition": t["condition"], "practice": t["practice"], "slot": entry["slot"]}
    given["aids"] = t["aids"]
    wrong = next((k for k in given if said[k] != given[k]), None)
    if wrong is not None:
        raise UserError(
            f"trial {order} of {code!r} in study {study!r} is {t['name']!r} ({t['condition']}, "
            f"{'practice' if t['practice'] else 'scored'}, slot {entry['slot']}, aids {_on(t['aids'])}) by the "
            f"server's register, but the upload says {wrong} {_said(said[wrong])}: a trial must have its allocation"
        )
    return {
        "study": study,
        "participant": code,
        "participant_number": entry["slot"] + 1,
        "trial": t["name"],
        "task": t["task"],
        "condition": t["condition"],
        "order": order,
        "cycle": t["cycle"],
        "practice": t["practice"],
        "aids": t["aids"],
        "allocation": {"by": "records server", "design": DESIGN, "slot": entry["slot"]},
        **{k: entry[k] for k in ("group", "year_of_training", "procedures_performed")},
    }


def _on(aids: dict) -> str:
    return "+".join(a for a, v in aids.items() if v) or "none"


def _said(value: Any) -> str:
    return _on(value) if isinstance(value, dict) else repr(value)


# -- the events a study session sets itself --------------------------------------------------------


def marked_points(pack: Any, side: str | None = None) -> list[tuple[float, float, float]]:
    """The points an insertion trial marks for the participant (the pack's ideal ones); both sides' when
    ``side`` is None (a records server checking a recording does not know the side)."""
    pts = pack.section("points")
    out = []
    for s in (side,) if side else ("left", "right"):
        for k in range(1, STUDY.mark_count + 1):
            p = pts.get(STUDY.ideal_point.format(k=k, side=s))
            if p is not None:
                x, y, z = np.asarray(p["position"], float)  # a point's position is a 3-vector (pack checks)
                out.append((float(x), float(y), float(z)))
    return out


def aid_events(trial: dict, now: float) -> list[tuple[float, Widget]]:
    """The trial's aids set (the others off), just after ``now``."""
    return [(now + 0.01, Widget(a, bool(trial["aids"].get(a, False)))) for a in AIDS]


def session_events(trial: dict, now: float, pack: Any, side: str) -> list[tuple[float, Any]]:
    """What a study session sets at a trial's start: its aids, a fresh attempt, and the marked points of an
    insertion trial."""
    events: list[tuple[float, Any]] = [*aid_events(trial, now), (now + RESET_AFTER_S, Widget(RESET, "all"))]
    if trial["task"] == MARKED_TASK:
        for k, p in enumerate(marked_points(pack, side), 1):
            events.append((now + 0.06 + 0.02 * k, PickPoint("skin", p)))
    return events


def check_session_events(recording: dict, trial: dict, pack: Any) -> None:
    """UserError unless the recording's events that are not window input are a study session's own (see
    ``session_events``): aid and reset widgets, and after the last reset only the marked points of an
    insertion trial; and unless the recording names this trial."""
    said = recording.get("protocol") or {}
    known = {k: trial[k] for k in ("study", "participant", "order", "trial", "condition", "practice")}
    known["slot"] = trial["allocation"]["slot"]
    wrong = next((k for k in known if not isinstance(said, dict) or said.get(k) != known[k]), None)
    if wrong is not None:
        raise UserError(f"the recording is not of this trial: its protocol's {wrong} is not the upload's")
    points = marked_points(pack)
    events = [e for e in recording.get("event") or [] if isinstance(e, dict)]
    resets = [i for i, e in enumerate(events) if e.get("kind") == "widget" and e.get("name") == RESET]
    last = resets[-1] if resets else -1
    for i, e in enumerate(events):
        if e.get("kind") == "widget" and (e.get("name") not in (*AIDS, RESET) or i > last):
            raise UserError(
                f"recording event {i + 1} sets widget {e.get('name')!r}, which a study session never sets there"
            )
        if e.get("kind") == "pick":
            p = np.asarray(e.get("point", ()), float)
            on_point = p.shape == (3,) and any(np.abs(p - q).max() <= POINT_TOLERANCE for q in points)
            if not on_point or (i > last and trial["task"] != MARKED_TASK):
                raise UserError(f"recording event {i + 1} marks a point the study session did not mark")


def check_replayed_aids(record: dict, trial: dict) -> None:
    """UserError unless the replayed attempt's aids are the trial's (the aids on at any time of it)."""
    got = {a: bool((record.get("aids") or {}).get(a, False)) for a in AIDS}
    if got != trial["aids"]:
        raise UserError(
            f"the replayed trial had aids {_on(got)}, but trial {trial['order']} ({trial['condition']}) of "
            f"{trial['participant']!r} has {_on(trial['aids'])}"
        )


def aid_locks(events: list[dict]) -> list[tuple[float, float]]:
    """When the session held a recording's aids locked (seconds): from ``LOCK_AFTER_S`` after each trial's
    start to the next trial's page, which frees them just before setting that trial's aids."""
    widgets = [(float(e["t"]), e.get("name")) for e in events if isinstance(e, dict) and e.get("kind") == "widget"]
    out = []
    for i, (t, name) in enumerate(widgets):
        if name == RESET:
            end = next((u for u, n in widgets[i + 1 :] if n in AIDS), float("inf"))
            out.append((t - RESET_AFTER_S + LOCK_AFTER_S, end - 0.005))
    return out


def hold_locks(app: Any, locks: list[tuple[float, float]]) -> None:
    """Lock or free the aids as the session did at the App's time: a replay's clicks on a locked aid are
    ignored, as the participant's were."""
    now = app.time.sim_time
    ws = app.resource(WidgetState)
    if any(a <= now < b for a, b in locks):
        ws.disable(*AIDS)
    elif locks and now >= locks[0][0]:  # before the first trial's lock the session had not touched them
        ws.enable(*AIDS)

"""`chainsim protocol PROTOCOL.toml`: run a study protocol of scripted trials (thesis 6.1.4) and print Table 6.1.

A protocol lists trials; each runs one or more input scripts headless with some aids switched on or
off, saves every attempt to the records store, and the mean error per condition is printed in the
shape of thesis Table 6.1 (location: landmark error; rotation and insertion: needle error), with the
thesis's own values beside it. Format:

    format = 1
    pack = "prp"                       # a pack name or folder
    title = "..."                      # optional
    [[trial]]
    name = "location-planes"
    task = "location"                  # location | insertion
    condition = "reference_planes"     # the table column (reference_planes, without_clues, local_viewer, ...)
    scripts = ["scripts/correct.toml"] # relative to the protocol file, else to the pack folder
    repeat = 1                         # runs of each script
    steps = 1200                       # optional, default: the pack's settings.steps
    [trial.aids]                       # aids not named are off
    reference_planes = true

Scripted attempts do not learn or tire, and aids change what a person sees, not what a script does:
the numbers measure the scripts. The protocol is the harness a study with people would use.
"""

from __future__ import annotations

import json
import math
import sys
import tomllib
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt

from chainsim.components.input_events import Widget
from chainsim.engine.errors import UserError
from chainsim.game.app.headless import run_pack
from chainsim.game.app.inputscript import load_script
from chainsim.game.packs import pack as packs
from chainsim.game.records.store import RecordStore
from chainsim.systems.procedures.prp.assessment import attempt_record

NAME = "protocol"
HELP = "run a study protocol of scripted trials, save the attempts, print a Table 6.1-style summary"

TASKS = ("location", "insertion")
TASK_TITLE = {"location": "Location", "insertion": "Rotation and insertion"}
TASK_METRIC = {"location": "landmark_error_mm", "insertion": "needle_error_mm"}
AIDS = ("skin_transparent", "reference_planes", "landmark_planes", "tip_view", "collision_signals")
#: thesis Table 6.1, mean error in cm, converted to mm
THESIS_MM = {
    ("location", "reference_planes"): 3.2,
    ("location", "without_clues"): 4.7,
    ("insertion", "local_viewer"): 32.0,
    ("insertion", "without_clues"): 44.0,
}
TOP_KEYS = {"format", "pack", "title", "description", "trial"}
TRIAL_KEYS = {"name", "task", "condition", "scripts", "script", "repeat", "steps", "aids"}


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP, description=HELP)
    p.add_argument("protocol", help="protocol TOML file (e.g. assets/prp/protocols/table61.toml)")
    p.add_argument("--db", metavar="PATH", help="records database (default: $CHAINSIM_DB or the user data folder)")
    p.add_argument(
        "--class",
        dest="class_name",
        default="study",
        metavar="NAME",
        help="class the attempts are saved under (default: study)",
    )
    p.add_argument(
        "--trainee", default="scripted", metavar="NAME", help="trainee the attempts are saved under (default: scripted)"
    )
    p.add_argument("--out", metavar="DIR", help="folder for each trial's summary.json, results.json and table61.png")
    p.add_argument("--pack-path", action="append", default=[], metavar="DIR")
    return p


def _err(where: str, msg: str):

    return UserError(f"{where}: {msg}")


def load_protocol(path: str | Path) -> dict:
    """Read and check a protocol; every problem is a one-line UserError naming the key."""

    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UserError(f"{path}: protocol file not found") from None
    except (OSError, UnicodeDecodeError) as e:
        raise UserError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    except tomllib.TOMLDecodeError as e:
        raise UserError(f"{path}: TOML syntax error: {e}") from None
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
    out = []
    names = set()
    for i, t in enumerate(trials, 1):
        w = f"{where}: trial {i}"
        if not isinstance(t, dict):
            raise _err(w, "must be a table")
        extra = sorted(set(t) - TRIAL_KEYS)
        if extra:
            raise _err(w, f"unknown key '{extra[0]}'; expected {', '.join(sorted(TRIAL_KEYS))}")
        name = t.get("name", f"trial-{i}")
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
        scripts = t.get("scripts", [t["script"]] if "script" in t else None)
        if not isinstance(scripts, list) or not scripts or not all(isinstance(s, str) and s for s in scripts):
            raise _err(w, "'scripts' must be a non-empty array of script paths")
        repeat = t.get("repeat", 1)
        if isinstance(repeat, bool) or not isinstance(repeat, int) or repeat < 1:
            raise _err(w, f"'repeat' must be a whole number >= 1, got {repeat!r}")
        steps = t.get("steps")
        if steps is not None and (isinstance(steps, bool) or not isinstance(steps, int) or steps < 1):
            raise _err(w, f"'steps' must be a whole number >= 1, got {steps!r}")
        aids = t.get("aids", {})
        if not isinstance(aids, dict):
            raise _err(w, "'aids' must be a table of true/false")
        for k, v in aids.items():
            if k not in AIDS:
                raise _err(w, f"unknown aid '{k}'; aids are {', '.join(AIDS)}")
            if not isinstance(v, bool):
                raise _err(w, f"aid '{k}' must be true or false, got {v!r}")
        out.append(
            {
                "name": name,
                "task": task,
                "condition": cond,
                "scripts": scripts,
                "repeat": repeat,
                "steps": steps,
                "aids": {a: bool(aids.get(a, False)) for a in AIDS},
            }
        )
    return {"path": path, "pack": data["pack"], "title": data.get("title", ""), "trials": out}


def _script_path(proto: dict, pack_root: Path, rel: str, where: str) -> Path:

    p = Path(rel)
    if p.is_absolute() and p.is_file():
        return p
    for base in (proto["path"].parent, pack_root):
        if (base / p).is_file():
            return base / p
    raise UserError(f"{where}: script '{rel}' not found next to the protocol or in the pack {pack_root}")


def mean_table(results: list[dict]) -> dict:
    """(task, condition) -> (mean, n_used, n_total) of the task's metric over the attempts."""
    groups: dict = {}
    for r in results:
        groups.setdefault((r["task"], r["condition"]), []).append(r["error_mm"])
    out = {}
    for key, vals in groups.items():
        used = [v for v in vals if v is not None]
        out[key] = (sum(used) / len(used) if used else None, len(used), len(vals))
    return out


def format_table(table: dict) -> str:
    cols = []
    for task in TASKS:
        for t, c in table:
            if t == task and (t, c) not in cols:
                cols.append((t, c))
        for t, c in THESIS_MM:
            if t == task and (t, c) in table and (t, c) not in cols:
                cols.append((t, c))
    width = 18
    head1 = " " * 26
    head2 = f"{'':26}"
    for task in TASKS:
        n = sum(1 for t, _ in cols if t == task)
        if n:
            head1 += TASK_TITLE[task].center(width * n)
    for t, c in cols:
        head2 += c.replace("_", " ").center(width)
    row = f"{'Mean error, this run (mm)':26}"
    count = f"{'  attempts scored / run':26}"
    thesis = f"{'Thesis Table 6.1 (mm)':26}"
    for key in cols:
        mean, used, total = table[key]
        row += (f"{mean:.2f}" if mean is not None else "-").center(width)
        count += f"{used}/{total}".center(width)
        th = THESIS_MM.get(key)
        thesis += (f"{th:.1f}" if th is not None else "-").center(width)
    lines = [
        "Performance test results (after thesis Table 6.1; location: landmark error, rotation and "
        "insertion: needle error E = Dist - R)",
        head1.rstrip(),
        head2.rstrip(),
        row.rstrip(),
        count.rstrip(),
        thesis.rstrip(),
    ]
    return "\n".join(lines)


def _plot(table: dict, path: Path) -> None:

    matplotlib.use("Agg")

    keys = [k for k in table if table[k][0] is not None]
    fig, ax = plt.subplots(figsize=(7, 3.5))
    x = range(len(keys))
    ax.bar([i - 0.2 for i in x], [table[k][0] for k in keys], width=0.4, label="this run")
    ax.bar([i + 0.2 for i in x], [THESIS_MM.get(k, 0.0) for k in keys], width=0.4, label="thesis Table 6.1")
    ax.set_xticks(list(x), [f"{TASK_TITLE[t]}\n{c.replace('_', ' ')}" for t, c in keys], fontsize=8)
    ax.set_ylabel("mean error (mm)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def run(args) -> int:

    proto = load_protocol(args.protocol)
    root, _scene = packs.resolve(proto["pack"], args.pack_path)
    pack = packs.load(root)
    out = Path(args.out) if args.out else None
    if out is not None:
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise UserError(f"--out {out}: cannot create folder ({e.strerror})") from None
    # check every script before anything runs or is saved
    plan = []
    for t in proto["trials"]:
        for s in t["scripts"]:
            path = _script_path(proto, root, s, f"{proto['path']}: trial '{t['name']}'")
            events = load_script(path)
            for r in range(t["repeat"]):
                plan.append((t, path, events, r))
    store = RecordStore(args.db)
    results = []
    try:
        for i, (t, path, events, r) in enumerate(plan, 1):
            print(
                f"[{i}/{len(plan)}] {t['name']}: {path.name} ({', '.join(a for a, v in t['aids'].items() if v) or 'no aids'})",
                file=sys.stderr,
                flush=True,
            )
            aid_events = [(0.0, Widget(a, v)) for a, v in t["aids"].items()]
            trial_out = str(out / f"{i:02d}-{t['name']}") if out is not None else None
            summary = run_pack(
                str(root), t["steps"], events=aid_events + list(events), out=trial_out, pack_paths=args.pack_path
            )
            a = summary.get("assessment")
            if not a:
                raise UserError(f"pack '{pack.name}' produced no assessment; protocols need a procedure pack")
            err = a.get(TASK_METRIC[t["task"]])
            saved = None
            if a.get("landmark_error_mm") is not None:
                rec = attempt_record(pack.name, a)
                rec["details"]["protocol"] = {
                    "trial": t["name"],
                    "task": t["task"],
                    "condition": t["condition"],
                    "script": path.name,
                    "repeat": r + 1,
                }
                saved = store.save_attempt(args.class_name, args.trainee, rec)
            results.append(
                {
                    "trial": t["name"],
                    "task": t["task"],
                    "condition": t["condition"],
                    "script": path.name,
                    "repeat": r + 1,
                    "error_mm": err,
                    "target": a.get("target"),
                    "skull_contacts": a.get("skull_contacts"),
                    "aids": t["aids"],
                    "attempt_id": saved,
                }
            )
    finally:
        store.close()
    table = mean_table(results)
    text = format_table(table)
    print(text)
    print(f"{len(results)} attempts saved to {store.path} (class {args.class_name}, trainee {args.trainee})")
    print("Scripted trials: aids change only what a person sees, so conditions differ only through their scripts.")
    if out is not None:
        data = {
            "protocol": str(proto["path"]),
            "pack": pack.name,
            "results": results,
            "table": [
                {
                    "task": k[0],
                    "condition": k[1],
                    "mean_error_mm": v[0],
                    "scored": v[1],
                    "runs": v[2],
                    "thesis_mm": THESIS_MM.get(k),
                }
                for k, v in table.items()
            ],
        }
        (out / "results.json").write_text(json.dumps(data, indent=2, allow_nan=False), encoding="utf-8")
        (out / "table61.txt").write_text(text + "\n", encoding="utf-8")
        _plot(table, out / "table61.png")
        print(f"results: {out / 'results.json'}, {out / 'table61.png'}")
    if any(v[0] is not None and not math.isfinite(v[0]) for v in table.values()):  # pragma: no cover
        return 1
    return 0

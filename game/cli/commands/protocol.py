"""`chainsim protocol PROTOCOL.toml`: a study after thesis 6.1.4 - with people at the window, or scripted.

Register first: `--register CODE --group novice|expert --year-of-training N --procedures-performed N`
enters the participant in the study's register (chainsim.game.study.register) and prints the slot and
condition order they are allocated; with `--records URL` the register and its one allocation sequence
are the records server's (signed in as a trainer of --class), else this machine's own, and the window
warns that another machine may give the same order. With `--records` the study's design (its trials and
their aids) is filed on the server too, and each trial is saved in the local records (--db) with its
recording and filed on the server through the outbox (`chainsim records sync` sends what an unreachable
server did not get): the server checks it against the participant's allocation and replays it
(chainsim.game.study.protocol). `--participant CODE` with those options registers at the start of
the session; without them the participant must be in the register already.

With people (`--participant NAME`): the trainer window opens for that participant and runs the
session of chainsim.game.study.session - the short pre-session questionnaire, the protocol's trials with
the aids on and off in an order counterbalanced between participants, the post-session ratings - and
ends with Table 6.1 over every participant of the study in the records database (also printed here).
Running the same participant again continues after their last saved trial; `--restart` starts over
from trial 1, after asking on the terminal (type yes): the earlier trials are retracted, kept in the
records but never counted, so no trial counts twice.

`--summary` prints that table and the mean ratings from the records without running anything (with
`--records`, from the trials filed on the server).

`--scripted` is the smoke test of the harness: each trial's input scripts run headless with its
aids, every attempt is saved (marked scripted), and the table of this run is printed. Scripted
attempts do not learn or tire, and aids change what a person sees, not what a script does: the
numbers measure the scripts, and the output says so.

Format:

    format = 1
    pack = "prp"                       # a pack name or folder
    title = "..."                      # optional
    practice = 1                       # practice trials per task before its scored ones (default 0)
    [[trial]]
    name = "location-planes"
    task = "location"                  # location | insertion
    condition = "reference_planes"     # the table column (reference_planes, without_clues, local_viewer, ...)
    scripts = ["scripts/correct.toml"] # --scripted only: relative to the protocol file, else to the pack
    repeat = 1                         # cycles with people; runs of each script when scripted
    steps = 1200                       # --scripted only; default: the pack's settings.steps
    [trial.aids]                       # aids not named are off
    reference_planes = true

Limits (docs/limits.md): repeat <= MAX_REPEAT, steps <= MAX_STEPS, and at most MAX_PROTOCOL_RUNS
runs (or trials) in all; everything, scripts, names and the records database included, is checked
before the first run. Scripted attempts are saved by the protocol itself: a Save pressed inside a
script saves nothing.
"""

from __future__ import annotations

import json
import logging
import math
import sys
from pathlib import Path
from types import SimpleNamespace

import matplotlib
import matplotlib.pyplot as plt

from chainsim.components.input_events import Widget
from chainsim.game.common.outputs import prepare_output_dir, write_text_atomic
from chainsim.game.packs import pack as packs
from chainsim.game.records.remote import RemoteRecords
from chainsim.game.records.store import RecordStore, check_target
from chainsim.game.study import protocol as study_protocol
from chainsim.game.study import register
from chainsim.game.study.protocol import load_protocol
from chainsim.game.study.questionnaire import POST, THESIS_RATINGS
from chainsim.game.study.session import (
    StudySession,
    current_attempts,
    every_condition,
    newest_questionnaires,
    plan,
    saved_trials,
    study_name,
)
from chainsim.game.study.table61 import (
    TASK_METRIC,
    TASK_TITLE,
    THESIS_MM,
    design_notes,
    format_ratings,
    format_table,
    ratings,
    study_rows,
    table,
)
from chainsim.game.trainer.headless import run_pack
from chainsim.game.trainer.inputscript import load_script
from chainsim.game.trainer.options import name
from chainsim.systems.engine import datafile, limits
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures import RECORDS_PROCEDURE, procedure_of, records_layout, records_study

#: the attempt as the records keep it (the fixed columns' procedure, chainsim.systems.procedures)
LAYOUT = records_layout()

logger = logging.getLogger(__name__)

NAME = "protocol"
HELP = (
    "run a study protocol with a participant at the window (or --scripted), save the attempts, "
    "print Table 6.1 over all participants"
)


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP, description=HELP)
    p.add_argument("protocol", help="protocol TOML file (e.g. assets/prp/protocols/table61.toml)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--participant", type=name("trainee"), metavar="NAME", help="run the session for this person in the window"
    )
    mode.add_argument("--scripted", action="store_true", help="run the trials' scripts headless (a smoke test)")
    mode.add_argument("--summary", action="store_true", help="print the study's results over all participants")
    mode.add_argument(
        "--register",
        type=name("participant"),
        metavar="CODE",
        help="enter a participant in the study's register (with --group, --year-of-training, "
        "--procedures-performed) and print the condition order they are allocated",
    )
    reg = p.add_argument_group("the participant's register entry (--register, or --participant's first session)")
    reg.add_argument("--group", metavar="GROUP", help="novice or expert")
    reg.add_argument("--year-of-training", metavar="N", help="year of training (a whole number, 0-80)")
    reg.add_argument("--procedures-performed", metavar="N", help="procedures of this kind performed (whole number)")
    p.add_argument(
        "--records",
        metavar="URL",
        help="records server that keeps the study's register, allocation sequence and design; the trials are "
        "filed there too (and kept in --db); --summary reads the server's records",
    )
    p.add_argument(
        "--restart",
        action="store_true",
        help="--participant: start over from trial 1 (asks first; the saved trials are retracted, not deleted)",
    )
    p.add_argument("--db", metavar="PATH", help="records database (default: $CHAINSIM_DB or the user data folder)")
    p.add_argument(
        "--class",
        dest="class_name",
        type=name("class"),
        default="study",
        metavar="NAME",
        help="class the study's attempts are saved under (default: study)",
    )
    p.add_argument(
        "--trainee",
        type=name("trainee"),
        default="scripted",
        metavar="NAME",
        help="--scripted: trainee the attempts are saved under (default: scripted)",
    )
    p.add_argument("--side", choices=("left", "right"), default="left", help="side of the insertion trials")
    p.add_argument("--out", metavar="DIR", help="folder for results.json, table61.txt and table61.png")
    p.add_argument("--pack-path", action="append", default=[], metavar="DIR")
    return p


def _script_path(proto: dict, pack_root: Path, rel: str, where: str) -> Path:

    p = Path(rel)
    if p.is_absolute() and p.is_file():
        return p
    for base in (proto["path"].parent, pack_root):
        if (base / p).is_file():
            return base / p
    raise UserError(f"{where}: script '{rel}' not found next to the protocol or in the pack {pack_root}")


def _plot(tab: dict, path: Path, label: str) -> None:
    matplotlib.use("Agg")
    keys = [k for k in tab if tab[k]["mean_error_mm"] is not None]
    fig, ax = plt.subplots(figsize=(7, 3.5))
    x = range(len(keys))
    ax.bar([i - 0.2 for i in x], [tab[k]["mean_error_mm"] for k in keys], width=0.4, label=label)
    ax.bar([i + 0.2 for i in x], [THESIS_MM.get(k) or 0.0 for k in keys], width=0.4, label="thesis Table 6.1")
    ax.set_xticks(list(x), [f"{TASK_TITLE[t]}\n{c.replace('_', ' ')}" for t, c in keys], fontsize=8)
    ax.set_ylabel("mean error (mm)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _write_out(out: Path | None, proto: dict, pack_name: str, tab: dict, text: str, label: str, extra: dict) -> None:
    if out is None:
        return
    data = {
        "protocol": str(proto["path"]),
        "study": study_name(proto),
        "pack": pack_name,
        **extra,
        "table": [{"task": k[0], "condition": k[1], **v} for k, v in tab.items()],
    }
    write_text_atomic(out / "results.json", json.dumps(data, indent=2, allow_nan=False), "--out")
    write_text_atomic(out / "table61.txt", text + "\n", "--out")
    _plot(tab, out / "table61.png", label)
    print(f"results: {out / 'results.json'}, {out / 'table61.png'}")


def _out_dir(args) -> Path | None:
    return prepare_output_dir(args.out, "--out") if args.out else None


def run(args) -> int:
    proto = load_protocol(args.protocol)
    if args.restart and not args.participant:
        raise UserError("--restart goes with --participant NAME (it starts that participant's session over)")
    if args.summary:
        return run_summary(args, proto)
    if args.register:
        return run_register(args, proto)
    if args.scripted or args.participant:
        check_study(args, proto)
    if args.scripted:
        return run_scripted(args, proto)
    if args.participant:
        return run_people(args, proto)
    raise UserError(
        "name the participant (--participant NAME) to run the study in the window, "
        "--scripted for the scripted smoke test, or --summary for the results so far"
    )


def check_study(args, proto: dict) -> None:
    """The protocol's pack runs the procedure whose study the study screens run: one line, exit 2, when
    its procedure declares no study (a cutting pack's), before any trial starts."""
    root, _scene = packs.resolve(proto["pack"], args.pack_path)
    toml = root / "pack.toml"
    manifest = datafile.parse_toml(
        datafile.read_text(toml, max_bytes=limits.MAX_MANIFEST_BYTES, what="pack.toml"), str(toml)
    )
    proc = procedure_of(manifest)
    if proc is None or proc.study is not records_study():
        runs = "no procedure" if proc is None else f"the {proc.name} procedure"
        raise UserError(
            f"{proto['path']}: pack '{proto['pack']}' runs {runs}, which declares no study; a protocol's pack must "
            f"run the procedure with a study ({RECORDS_PROCEDURE.name})"
        )


def covariates(args) -> dict | None:
    """The register entry's covariates given on the command line; None when none is; all three or none."""
    given = {"group": args.group, "year_of_training": args.year_of_training}
    given["procedures_performed"] = args.procedures_performed
    if all(v is None for v in given.values()):
        return None
    missing = [k for k, v in given.items() if v is None]
    if missing:
        flag = "--" + missing[0].replace("_", "-")
        raise UserError(
            f"{flag} is missing; a register entry needs --group, --year-of-training and --procedures-performed"
        )
    return given


def allocation(args, proto: dict, code: str) -> dict:
    """The participant's allocation (chainsim.game.study.register.allocate), registering them if asked."""
    if args.records:  # the server checks each uploaded trial against the study's design filed here
        register.file_design_on_server(args.records, args.db, study_name(proto), study_protocol.design(proto))
    return register.allocate(study_name(proto), args.class_name, code, covariates(args), args.records, args.db)


def run_register(args, proto: dict) -> int:
    """--register CODE: enter the participant in the register; print the slot and the order it gives."""
    if covariates(args) is None:
        raise UserError("--register needs --group, --year-of-training and --procedures-performed")
    if args.records is None:
        check_target(args.db)
    got = allocation(args, proto, args.register)
    trials = plan(proto, got["slot"])
    print(f"{args.register} is in the register of study '{study_name(proto)}' ({got['by']}): slot {got['slot']}")
    print("trials: " + ", ".join(("practice " if t["practice"] else "") + t["name"] for t in trials))
    if got.get("warning"):
        logger.warning(got["warning"])
    return 0


def run_summary(args, proto: dict) -> int:
    """Table 6.1 and the ratings over every participant of the study in the records."""
    study = study_name(proto)
    attempts, questionnaires, where = _summary_records(args)
    attempts, questionnaires = current_attempts(attempts), newest_questionnaires(questionnaires)
    left_out = 0
    if proto.get("require_witnessed"):
        kept = [a for a in attempts if a.get("source") == "witnessed"]
        left_out, attempts = len(attempts) - len(kept), kept
    rows = [r for r in study_rows(attempts, study) if not r["scripted"]]
    if left_out:
        print(f"{left_out} attempt(s) left out: the study requires witnessed attempts (browser trainer)")
    if not rows:
        raise UserError(
            f"no attempts of study '{study}' by people in class '{args.class_name}' in {where}; "
            f"run a session first: chainsim protocol {args.protocol} --participant NAME"
        )
    tab = every_condition(table(rows), proto)
    people = len({r["participant"] for r in rows})
    text = format_table(tab, f"{people} participants")
    rates = ratings(questionnaires, study)
    print(text)
    for line in design_notes(attempts, study):  # under the table: its rows stay where they were
        print(line)
    print()
    print(format_ratings(rates, {q.id: q.text for q in POST}, THESIS_RATINGS))
    _write_out(_out_dir(args), proto, proto["pack"], tab, text, "participants", {"ratings": rates})
    return 0


def _summary_records(args) -> tuple[list[dict], list[dict], str]:
    """(attempts, questionnaires, where) of --class: the records server's with --records (the trials
    filed there; questionnaires stay on the machine that asked them), else --db's."""
    if args.records:
        with RemoteRecords(args.records, args.db) as rr:
            return rr.list_attempts(args.class_name), [], rr.where
    with RecordStore(args.db) as store:
        try:
            return store.list_attempts(args.class_name), store.list_questionnaires(args.class_name), str(store.path)
        except UserError:
            return [], [], str(store.path)


def run_people(args, proto: dict) -> int:
    """The session of chainsim.game.study.session in the trainer window; Table 6.1 over everyone at the end."""
    from chainsim.game.trainer.window import run_window  # noqa: PLC0415 - pyglet: only when a window is wanted

    check_target(args.db)  # a mistyped or read-only database is refused before the window opens
    out = _out_dir(args)
    db = args.db
    allocated = allocation(args, proto, args.participant)  # in the register before the first trial
    if allocated.get("warning"):
        logger.warning(allocated["warning"])
    if args.restart:
        restart(args, proto)
    holder: dict = {}

    def make_session(app):
        holder["session"] = StudySession(
            app,
            proto,
            args.participant,
            args.class_name,
            db,
            side=args.side,
            restart=args.restart,
            allocation=allocated,
            records=args.records,
        )
        return holder["session"]

    window_args = SimpleNamespace(
        pack=proto["pack"],
        pack_path=args.pack_path,
        input=None,
        exit_after=None,
        screenshot=None,
        record=None,
        db=db,
        # each trial is kept in --db with its recording; with --records the session files it on the server
        # too (StudySession: the outbox, so a server out of reach gets it with the next sync)
        records=None,
        class_name=args.class_name,
        trainee=args.participant,
    )
    rc = run_window(window_args, session=make_session)
    session = holder.get("session")
    if session is None or not session.summary:
        logger.warning(f"session of {args.participant} ended early; what was done is saved")
        return rc
    print(session.summary)
    _write_out(
        out,
        proto,
        proto["pack"],
        session.table,
        session.summary,
        "participants",
        {"participant": args.participant, "trials": session.done_trials, "ratings": session.ratings},
    )
    return rc


def restart(args, proto: dict) -> None:
    """--restart: ask on the terminal, then retract the participant's saved trials of this study (the
    records keep them, marked retracted with the reason; tables never count them)."""
    study = study_name(proto)
    with RecordStore(args.db) as store:
        try:
            attempts = store.list_attempts(args.class_name)
        except UserError:  # no such class yet: nothing to start over from
            attempts = []
        saved = saved_trials(attempts, study, args.participant)
        if not saved:
            print(f"{args.participant} has no saved trials of study '{study}'; the session starts at trial 1.")
            return
        orders = sorted(saved)
        sys.stderr.write(
            f"{args.participant} has {len(saved)} saved trials of study '{study}' (trials "
            f"{', '.join(map(str, orders))}). Starting over retracts them: the records keep them, marked "
            "retracted, and the study's tables no longer count them. Type yes to start over at trial 1: "
        )
        sys.stderr.flush()
        answer = sys.stdin.readline().strip().lower() if sys.stdin is not None else ""
        if answer not in ("yes", "y"):
            raise UserError(f"not restarted: {args.participant}'s saved trials are unchanged")
        for order in orders:
            store.retract_attempt(
                saved[order]["id"], args.participant, f"participant restarted study '{study}' (--restart)"
            )
    print(f"retracted {len(saved)} trials of {args.participant}; the session starts at trial 1")


def _scripted_plan(proto: dict, root) -> list[tuple]:
    """(trial, script path, its events, repeat) for every attempt of a --scripted run; every script is
    checked before anything runs or is saved."""
    plan = []
    for t in proto["trials"]:
        if not t["scripts"]:
            raise UserError(f"{proto['path']}: trial '{t['name']}' has no scripts; --scripted runs need them")
        for s in t["scripts"]:
            path = _script_path(proto, root, s, f"{proto['path']}: trial '{t['name']}'")
            events = load_script(path)
            for r in range(t["repeat"]):
                plan.append((t, path, events, r))
    return plan


def run_scripted(args, proto: dict) -> int:
    """The smoke test: every trial's scripts headless, saved and tabled - and labelled as scripted."""
    root, _scene = packs.resolve(proto["pack"], args.pack_path)
    pack = packs.load(root, args.pack_path)
    check_target(args.db)  # a mistyped or read-only database is refused before the first trial
    out = _out_dir(args)
    plan = _scripted_plan(proto, root)
    study = study_name(proto)
    logger.warning("SCRIPTED smoke test: input scripts, not people, make these attempts.")
    store = RecordStore(args.db)
    results = []
    try:
        for i, (t, path, events, r) in enumerate(plan, 1):
            aids = ", ".join(a for a, v in t["aids"].items() if v) or "no aids"
            logger.info(f"[{i}/{len(plan)}] {t['name']}: {path.name} ({aids})")
            aid_events = [(0.0, Widget(a, v)) for a, v in t["aids"].items()]
            trial_out = str(out / f"{i:02d}-{t['name']}") if out is not None else None
            summary = run_pack(
                str(root),
                t["steps"],
                events=aid_events + list(events),
                out=trial_out,
                pack_paths=args.pack_path,
                save="the protocol saves each attempt itself",
            )
            a = summary.get("assessment")
            if not a:
                raise UserError(f"pack '{pack.name}' produced no assessment; protocols need a procedure pack")
            err = a.get(TASK_METRIC[t["task"]])
            saved = None
            proc = procedure_of(pack.manifest)
            if a.get(LAYOUT.mark_error) is not None and proc is not None and proc.attempt_record is not None:
                rec = proc.attempt_record(pack.name, a)
                rec["details"]["protocol"] = {
                    "study": study,
                    "participant": args.trainee,
                    "scripted": True,
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
                    "xray_shots": a.get("xray_shots", 0),
                    "aids": t["aids"],
                    "attempt_id": saved,
                    "participant": args.trainee,
                    "scripted": True,
                }
            )
    finally:
        store.close()
    tab = table(results)
    text = format_table(tab, "scripted run")
    print(text)
    print(f"{len(results)} attempts saved to {store.path} (class {args.class_name}, trainee {args.trainee})")
    print(
        "SCRIPTED: aids change only what a person sees, so these conditions differ only through their scripts; "
        "for a study with people use --participant NAME."
    )
    _write_out(out, proto, pack.name, tab, text, "scripted run", {"scripted": True, "results": results})
    if any(v["mean_error_mm"] is not None and not math.isfinite(v["mean_error_mm"]) for v in tab.values()):
        return 1  # pragma: no cover
    return 0

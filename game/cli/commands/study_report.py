"""`chainsim study-report`: does each metric of a pack tell experts from novices? Evidence a programme can file.

Reads a pack's attempts from a records database (``--db``, ``--class``; ``--study``, ``--task`` and
``--condition`` narrow them to one study of ``chainsim protocol``, one task and one condition), takes
each participant's experience group from a register (``--groups FILE``, a CSV: participant, group
(novice or expert), year_of_training, procedures_performed) or from the attempts' own
``details.protocol.group``, and writes into ``--out DIR`` one PNG per metric of the pack's [metrics],
learning-curves.png, statistics.csv and report.md (``chainsim.game.study.validity_report``), and
benchmarks.toml: the pass marks a programme may adopt as its own benchmarks, which
``--write-benchmarks PACK_DIR`` writes into a (not built-in) pack (``chainsim.game.study.programme_benchmarks``).

``--demo-cohort N`` analyses a synthetic cohort of N participants instead (``chainsim.game.records.
cohort``: values drawn from normal distributions with Cohen's d = ``--effect`` between the groups);
its report, like any made from scripted attempts, opens with "synthetic data: not evidence".
docs/validity.md walks through a study from protocol to report.
"""

from __future__ import annotations

import argparse
from datetime import date
from pathlib import Path

from chainsim.game.common.outputs import prepare_output_dir
from chainsim.game.packs import pack as packs
from chainsim.game.packs.discovery import BUILTIN_DIR
from chainsim.game.packs.validation import PackError
from chainsim.game.records.backend import is_postgres, redact
from chainsim.game.records.store import RecordStore
from chainsim.game.study import cohort, programme_benchmarks, validity_report
from chainsim.game.study.validity import RESAMPLES
from chainsim.game.study.validity_data import UNITS, Selection, read_register, select
from chainsim.game.trainer.options import name
from chainsim.systems.engine import argtypes, atomicfile
from chainsim.systems.engine.errors import UserError

NAME = "study-report"
HELP = "known-groups validity of a pack's metrics: novices against experts, pass marks, a report to file"

_EPILOG = """\
examples:
  chainsim study-report --pack prp --db study.sqlite3 --class study --groups register.csv --out report/
  chainsim study-report --pack prp --demo-cohort 36 --out demo/      (synthetic data: not evidence)
register CSV columns: participant, group (novice or expert), year_of_training, procedures_performed
"""


def add_parser(sub):
    p = sub.add_parser(
        NAME, help=HELP, description=HELP, epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--pack", required=True, help="the pack (name or folder) whose [metrics] are analysed")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for report.md, statistics.csv and the PNGs")
    p.add_argument("--db", metavar="PATH", help="records database (default: $CHAINSIM_DB or the user data folder)")
    p.add_argument(
        "--class",
        dest="class_name",
        type=name("class"),
        default="study",
        metavar="NAME",
        help="class whose attempts are read (default: study, where chainsim protocol saves)",
    )
    p.add_argument(
        "--groups",
        metavar="FILE",
        help="register CSV: participant, group, year_of_training, "
        "procedures_performed (default: each attempt's details.protocol.group)",
    )
    p.add_argument("--study", metavar="NAME", help="only attempts of this study (details.protocol.study)")
    p.add_argument("--task", metavar="NAME", help="only attempts of this task (details.protocol.task)")
    p.add_argument("--condition", metavar="NAME", help="only attempts of this condition (details.protocol.condition)")
    p.add_argument(
        "--unit",
        choices=UNITS,
        default="median",
        help="a participant's value: the median of their attempts' values (default), their first or their last",
    )
    p.add_argument("--seed", type=argtypes.count(0, 2**32 - 1), default=0, help="bootstrap seed (default 0)")
    p.add_argument(
        "--resamples",
        type=argtypes.count(1000, 100_000),
        default=RESAMPLES,
        help=f"bootstrap resamples per interval (default {RESAMPLES})",
    )
    demo = p.add_argument_group("synthetic cohort (for demonstrations and tests; not evidence)")
    demo.add_argument(
        "--demo-cohort",
        type=argtypes.count(2, cohort.MAX_PARTICIPANTS),
        metavar="N",
        help="analyse N synthetic participants, half novices, instead of a database",
    )
    demo.add_argument(
        "--effect",
        type=argtypes.real(-10.0, 10.0, what="an effect size"),
        default=0.8,
        help="--demo-cohort: Cohen's d between the groups' levels (default 0.8)",
    )
    demo.add_argument(
        "--trials",
        type=argtypes.count(1, cohort.MAX_TRIALS),
        default=5,
        help="--demo-cohort: attempts per participant (default 5)",
    )
    p.add_argument(
        "--write-benchmarks",
        metavar="PACK_DIR",
        help="also write the marks of the metrics that separate the groups into this pack folder's pack.toml "
        "(benchmark_basis programme, the data as benchmark_source; the old file kept as pack.toml.bak); "
        "a built-in pack is never rewritten: copy it first",
    )
    p.add_argument("--pack-path", action="append", default=[], metavar="DIR")
    return p


def pack_metrics(ref: str, pack_paths) -> tuple[str, dict]:
    """The pack's name and its [metrics] section (the pack checked, its meshes not loaded)."""
    root, _scene = packs.resolve(ref, pack_paths)
    pack, problems = packs.validate(root, load_meshes=False, pack_paths=pack_paths)
    if problems or pack is None:
        raise PackError(problems)
    metrics = dict(pack.section("metrics"))
    if not metrics:
        raise UserError(f"pack '{pack.name}' declares no [metrics]; a validity study compares metrics")
    return pack.name, metrics


def _from_database(args, pack_name: str) -> tuple[Selection, str]:
    register = read_register(args.groups) if args.groups else None
    with RecordStore(args.db, create=False) as store:
        attempts = store.list_attempts(args.class_name)
        where = redact(args.db) if is_postgres(args.db) else str(store.path)
    narrow = {"study": args.study, "task": args.task, "condition": args.condition}
    sel = select(attempts, register, pack=pack_name, **narrow)
    narrowed = "".join(f", {k} {v}" for k, v in narrow.items() if v)
    source = f"records database {where}, class {args.class_name}{narrowed}, pack {pack_name}"
    if args.groups:
        source += f"; groups from the register {args.groups}"
    if not sel.series:
        left = "; ".join(f"{n} {why}" for why, n in sorted(sel.left_out.items())) or "none at all"
        hint = "" if args.groups else " (give --groups FILE to name each participant's group)"
        raise UserError(f"no attempts to analyse in class {args.class_name!r} of {where}: left out {left}{hint}")
    return sel, source


def _from_cohort(args, pack_name: str, metrics: dict) -> tuple[Selection, str]:
    if args.db or args.groups or args.study or args.task or args.condition:
        raise UserError(
            "--demo-cohort draws its own attempts: leave out --db, --groups, --study, --task and --condition"
        )
    drawn = cohort.build(
        metrics,
        args.demo_cohort,
        pack=pack_name,
        effect=args.effect,
        trials=args.trials,
        seed=args.seed,
        learning=1.0,
        trial_sd=0.3,
    )
    sel = select(cohort.as_listed(drawn), None, pack=pack_name)
    source = (
        f"a synthetic cohort of {args.demo_cohort} participants with {args.trials} attempts each, drawn by "
        f"chainsim's cohort builder with Cohen's d = {args.effect:g} between the groups' levels, novices "
        f"learning more over their attempts (seed {args.seed})"
    )
    return sel, source


def _target_pack(args, pack_name: str) -> Path | None:
    """The pack folder --write-benchmarks names, checked before any analysis: a pack of the same name,
    not a built-in one, from people's attempts."""
    if not args.write_benchmarks:
        return None
    root = Path(args.write_benchmarks).resolve()
    if args.demo_cohort:
        raise UserError("--write-benchmarks takes marks from people's attempts: a --demo-cohort is synthetic")
    if root == BUILTIN_DIR.resolve() or BUILTIN_DIR.resolve() in root.parents:
        raise UserError(
            f"--write-benchmarks {args.write_benchmarks}: a built-in pack is never rewritten; copy the folder "
            "and give the copy (and --pack COPY)"
        )
    if not (root / "pack.toml").is_file():
        raise UserError(f"--write-benchmarks {args.write_benchmarks}: no pack.toml there; expected a pack folder")
    other, problems = packs.validate(root, load_meshes=False, pack_paths=args.pack_path)
    if problems or other is None:
        raise PackError(problems)
    if other.name != pack_name:
        raise UserError(f"--write-benchmarks {args.write_benchmarks}: pack '{other.name}', expected '{pack_name}'")
    return root


def _benchmarks(args, study, out: Path, target: Path | None) -> None:
    """benchmarks.toml beside the report, and the marks into --write-benchmarks' pack when given."""
    named = [f"{k} {v}" for k, v in (("study", args.study), ("task", args.task), ("condition", args.condition)) if v]
    where = "a synthetic cohort" if args.demo_cohort else ", ".join(named) or f"class {args.class_name}"
    marks, none = programme_benchmarks.proposals(study, where, date.today().isoformat())
    _save_text(out / programme_benchmarks.FILE, programme_benchmarks.toml_text(study, marks, none))
    print(f"benchmarks a programme may adopt: {out / programme_benchmarks.FILE}")
    if target is None:
        return
    if study.synthetic:
        raise UserError(
            f"--write-benchmarks: {validity_report.SYNTHETIC} (scripted or drawn attempts); pack left as it was"
        )
    if not marks:
        print(f"no metric separates the groups with a pass mark: {target / 'pack.toml'} left as it was")
        return

    def check(root: Path) -> list:
        return packs.validate(root, load_meshes=False, pack_paths=args.pack_path)[1]

    backup = programme_benchmarks.apply(target, marks, check)
    print(f"wrote {len(marks)} programme benchmarks into {target / 'pack.toml'} ({', '.join(m.name for m in marks)});")
    print(f"  its previous text is in {backup}")


def _save_text(path: Path, text: str) -> None:
    try:
        atomicfile.write_text(path, text)
    except OSError as e:
        raise UserError(f"--out {path}: cannot write ({e.strerror or e})") from None


def run(args) -> int:
    pack_name, metrics = pack_metrics(args.pack, args.pack_path)
    target = _target_pack(args, pack_name)
    if args.demo_cohort:
        sel, source = _from_cohort(args, pack_name, metrics)
    else:
        sel, source = _from_database(args, pack_name)
    out = prepare_output_dir(args.out, "--out")  # made once there is something to write into it
    study = validity_report.analyse(
        sel,
        metrics,
        pack=pack_name,
        source=source,
        unit=args.unit,
        seed=args.seed,
        resamples=args.resamples,
        synthetic_cohort=bool(args.demo_cohort),
    )
    md = validity_report.write(study, Path(out))
    if study.synthetic:
        print(f"{validity_report.SYNTHETIC.upper()}: {source}")
    for r in study.results:
        verdict = "separates" if r.separates else "FLAGGED: " + "; ".join(r.notes)
        effect = f"Cliff's delta {validity_report.number(r.delta)} {validity_report.interval(r.delta_ci)}"
        print(f"{r.label}: {effect}, {verdict}")
    print(f"report: {md}")
    _benchmarks(args, study, Path(out), target)
    return 0

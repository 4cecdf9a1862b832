"""`chainsim study`: the speed-accuracy study and ChainMail calibration (tools/study, thesis 6.2)."""

from __future__ import annotations

import logging
import os
import platform
from pathlib import Path

from chainsim.game.common.outputs import prepare_output_dir
from chainsim.systems.engine import argtypes, limits
from chainsim.systems.engine.errors import UserError
from chainsim.tools.bench import pack_costs
from chainsim.tools.study import calibrate as cal
from chainsim.tools.study import long_runs, report, speed_accuracy, surgical, surgical_report
from chainsim.tools.study.scenes import SCENES

logger = logging.getLogger(__name__)

NAME = "study"
HELP = "speed-accuracy study of ChainMail vs FEM and mass-spring; calibrate ChainMail presets"


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP, description=HELP)
    s = p.add_subparsers(dest="study_cmd", metavar="{speed-accuracy,surgical,calibrate}")
    sg = s.add_parser(
        "surgical",
        help="the trade at surgical scale: a 30 mm tissue block, 5-0.6 mm elements, 1-100 kPa; writes "
        "report.md, a plot, results.json and the model table rows",
    )
    sg.add_argument("--quick", action="store_true", help="two mesh sizes, one material (about a minute)")
    sg.add_argument(
        "--parts",
        default="table",
        help="comma-separated: table (every setting after half a second, the model table's rows), long (holds, "
        "drags and far pulls for seconds, tools/study/long_runs.py: long-runs.md and .json; the 1.25 mm mesh, "
        "2.5 mm with --quick), stiffness (the 3 mm lift held from rest for 5 s at four stiffnesses up to nu "
        "0.499: frames to 10/5/1 % of the model's own answer and of the FEM, tools/study/long_runs.py: stiffness.md "
        "and .json); default table",
    )
    sg.add_argument("--out", required=True, help="output folder")
    sg.add_argument(
        "--table", default=None, help="model table to merge the rows into (assets/presets/models.toml in a checkout)"
    )
    sa = s.add_parser("speed-accuracy", help="run the study; writes report.md, PNG plots, results.json")
    sa.add_argument("--quick", action="store_true", help="small meshes and fewer loads (< 3 min)")
    sa.add_argument("--out", required=True, help="output folder")
    sa.add_argument("--scenes", default=None, help="comma-separated subset of block,sheet,cantilever (default: all)")
    sa.add_argument(
        "--pack-steps",
        type=argtypes.steps,
        default=120,
        help="steps per built-in pack for the frame-cost table (0 skips it)",
    )
    c = s.add_parser("calibrate", help="fit ChainMail alpha_min/alpha_max/beta/relaxation to FEM")
    c.add_argument(
        "--nu",
        type=argtypes.real(-1.0, 0.5, low_open=True, high_open=True, what="a Poisson ratio"),
        default=None,
        help="Poisson ratio, in (-1, 0.5) (required unless --shipped)",
    )
    c.add_argument(
        "--E",
        type=argtypes.real(0.0, 1e15, low_open=True),
        default=None,
        help="Young's modulus [Pa]; sets the strain level a gentle tool traction produces",
    )
    c.add_argument(
        "--strain", type=argtypes.real(0.0, 1.0, low_open=True), default=None, help="fit at this strain instead"
    )
    c.add_argument("--name", required=False, help="preset name (table in the TOML file)")
    c.add_argument(
        "--out",
        default="materials.toml",
        help="presets TOML file to add the preset to (default ./materials.toml; the shipped presets are "
        "assets/presets/materials.toml in a source checkout)",
    )
    c.add_argument(
        "--block-n",
        type=argtypes.count(5, limits.MAX_STUDY_BLOCK),
        default=8,
        help="nodes per edge of the calibration block (default 8: 512 nodes, ~15 s)",
    )
    c.add_argument(
        "--shipped", action="store_true", help="recompute every preset shipped with the project instead of one"
    )
    p.set_defaults(_study_parser=p)
    return p


def platform_line() -> str:
    """The machine a figure came from, in a few words."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, load {load:.1f}"


def _long_runs(args, out: Path) -> None:
    """The long runs on the study's block (the 2.5 mm mesh with --quick), their FEM solutions kept for the
    next run (long_runs.CACHE)."""
    element = long_runs.QUICK_MM if args.quick else long_runs.DEFAULT_MM
    results = long_runs.run(element, cache=long_runs.CACHE, progress=lambda m: logger.info(f"study   {m}"))
    command = "chainsim study surgical --parts long" + (" --quick" if args.quick else "") + f" --out {args.out}"
    md = long_runs.write(results, out, command, platform_line())
    print(md.read_text(encoding="utf-8"))


def _stiffness(args, out: Path) -> None:
    """The held lift at each stiffness (long_runs.stiffness), on the same mesh as the long runs."""
    element = long_runs.QUICK_MM if args.quick else long_runs.DEFAULT_MM
    results = long_runs.stiffness(element, cache=long_runs.CACHE, progress=lambda m: logger.info(f"study   {m}"))
    command = "chainsim study surgical --parts stiffness" + (" --quick" if args.quick else "") + f" --out {args.out}"
    md = long_runs.write_stiffness(results, out, command, platform_line())
    print(md.read_text(encoding="utf-8"))


def run(args) -> int:

    cmd = getattr(args, "study_cmd", None)
    if cmd == "speed-accuracy":
        scenes = None
        if args.scenes:
            scenes = [x.strip() for x in args.scenes.split(",") if x.strip()]
            bad = [x for x in scenes if x not in SCENES]
            if bad:
                raise UserError(f"--scenes: unknown scene(s) {', '.join(bad)}; expected some of {', '.join(SCENES)}")
        prepare_output_dir(args.out, "--out")
        results = speed_accuracy.run(args.quick, args.out, scenes)
        summaries: list[dict]
        summaries, note = ([], "skipped (--pack-steps 0)")
        if args.pack_steps:
            summaries, note = pack_costs.measure(args.pack_steps)
        md = report.write(results, args.out, summaries, note)
        logger.info(f"wrote {md}")
        print(md)
        return 0
    if cmd == "surgical":
        if args.table is not None and not Path(args.table).parent.is_dir():
            raise UserError(f"--table {args.table}: its folder does not exist (expected a model table's path)")
        parts = long_runs.parts(getattr(args, "parts", None), ("table", "long", "stiffness"), "table")
        out = prepare_output_dir(args.out, "--out")
        if "table" in parts:
            results = surgical.run("quick" if args.quick else "full", progress=lambda m: logger.info(f"study   {m}"))
            command = "chainsim study surgical" + (" --quick" if args.quick else "") + f" --out {args.out}"
            md = surgical_report.write(results, args.out, command, platform_line(), args.table)
            print(md)
        if "long" in parts:
            _long_runs(args, out)
        if "stiffness" in parts:
            _stiffness(args, out)
        return 0
    if cmd == "calibrate":
        if args.E is not None and not args.E > 0:
            raise UserError(f"--E must be a positive modulus in Pa, got {args.E}")
        jobs = [(n, E, nu) for n, E, nu in cal.SHIPPED] if args.shipped else [(args.name, args.E, args.nu)]
        if not 5 <= args.block_n <= 16:
            raise UserError(f"--block-n must lie in [5, 16], got {args.block_n}")
        if not args.shipped and not args.name:
            raise UserError("--name is required (the preset's table name), or use --shipped")
        if not args.shipped and args.nu is None:
            raise UserError("--nu is required (Poisson ratio in (-1, 0.5)), or use --shipped")
        for name, E, nu in jobs:
            logger.info(f"calibrate {name}: nu={nu:g} E={E}")
            res = cal.fit(
                nu,
                E,
                None if args.shipped else args.strain,
                n=args.block_n,
                progress=lambda m: logger.info(f"calibrate   {m}"),
            )
            for w in res["warnings"]:
                logger.warning(f"calibrate: {w}")
            path = cal.write_preset(name, res, args.out)
            print(
                f"{name}: alpha_min={res['alpha_min']} alpha_max={res['alpha_max']} "
                f"beta={res['beta']} relax_iterations={res['relax_iterations']} "
                f"fitted_error={res['fitted_error']} -> {path}"
            )
        return 0
    raise UserError("study needs a subcommand: speed-accuracy or calibrate")

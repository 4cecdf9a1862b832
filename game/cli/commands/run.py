"""`chainsim run PACK[/SCENE] --headless --steps N [--input SCRIPT] [--record FILE] [--out DIR]`."""

from __future__ import annotations

import json
from pathlib import Path

from chainsim.game.records import remote
from chainsim.game.trainer.haptic_plot import plot_trace
from chainsim.game.trainer.headless import run_pack
from chainsim.game.trainer.options import (
    add_device_argument,
    add_mode_arguments,
    add_records_arguments,
    user_settings,
    window_size,
)
from chainsim.systems.engine import argtypes
from chainsim.systems.engine.errors import UserError

NAME = "run"
HELP = "run a pack without a window and write OUT/summary.json"


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP)
    p.add_argument("pack", help="PACK or PACK/SCENE (a pack name or folder)")
    p.add_argument("--headless", action="store_true", help="no window (the only mode of `run`; accepted for clarity)")
    p.add_argument(
        "--steps", type=argtypes.steps, default=None, help="fixed simulation steps (default: the pack's settings.steps)"
    )
    p.add_argument("--input", metavar="SCRIPT", help="input script (.toml or .json), see docs/input-scripts.md")
    p.add_argument("--record", metavar="FILE", help="save the session (events, digest) for `chainsim replay`")
    p.add_argument("--out", metavar="DIR", help="folder for summary.json (and frames)")
    p.add_argument("--dt", type=argtypes.dt, default=None, help="override the fixed step (seconds)")
    p.add_argument(
        "--screenshot-every", type=argtypes.steps, default=0, metavar="K", help="write a PNG every K frames (needs EGL)"
    )
    p.add_argument(
        "--size", type=window_size, default=None, metavar="WxH", help="off-screen frame size for screenshots"
    )
    add_mode_arguments(p)
    add_records_arguments(p)
    p.add_argument("--pack-path", action="append", default=[], metavar="DIR")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    add_device_argument(p)
    return p


def run(args) -> int:
    if args.screenshot_every and not args.out:
        raise UserError("--screenshot-every needs --out DIR for the frames")
    if args.records:
        remote.sync_quietly(args.records, args.db)  # what an earlier session left in the queue
    summary = run_pack(
        args.pack,
        args.steps,
        script=args.input,
        record=args.record,
        out=args.out,
        pack_paths=args.pack_path,
        dt=args.dt,
        screenshot_every=args.screenshot_every,
        size=args.size,
        settings=user_settings(args),
        device=args.device,
    )
    if args.device and args.out:  # the forces drawn beside the trace they come from
        out = Path(args.out)
        plot_trace(out / "haptic_trace.csv", out / "haptic_force.png", f"{args.pack}, {args.device}")
    if args.json:
        print(json.dumps(summary, indent=2, sort_keys=True))
    else:
        print(
            f"{summary['pack']}/{summary['scene']}: {summary['steps']} steps, "
            f"{summary['simulated_time_s']:.3f} s simulated, digest {summary['digest'][:16]}"
        )
        for line in summary.get("saves", ()):  # where each Save on a records server went
            print(f"  {line}")
        if "assessment" in summary:
            for k, v in summary["assessment"].items():
                if not isinstance(v, (dict, list)):
                    print(f"  {k}: {v}")
        if args.out:
            print(f"  summary: {args.out}/summary.json")
    return 0

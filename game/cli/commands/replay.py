"""`chainsim replay FILE`: run a recorded session again and check it reaches the same digest."""

from __future__ import annotations

import math

from chainsim.engine.errors import UserError
from chainsim.game.app.headless import run_pack
from chainsim.game.app.inputscript import parse_events, read_file

NAME = "replay"
HELP = "replay a recorded session and compare its final digest"


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP)
    p.add_argument("file", help="recording written by `chainsim run --record` or `chainsim play --record`")
    p.add_argument("--out", metavar="DIR", help="folder for summary.json")
    p.add_argument("--pack-path", action="append", default=[], metavar="DIR")
    return p


def run(args) -> int:

    data = read_file(args.file)
    if not isinstance(data, dict) or data.get("chainsim") != "recording":
        raise UserError(f"{args.file}: not a chainsim recording (expected the JSON written by --record)")
    for key, kind in (("pack", str), ("scene", str), ("digest", str), ("steps", int), ("dt", float)):
        v = data.get(key)
        if not isinstance(v, kind) or isinstance(v, bool) or (kind is float and not math.isfinite(v)):
            raise UserError(f"{args.file}: field '{key}' missing or not a {kind.__name__}")
    events = parse_events(data, args.file)
    ref = data["pack"].split("/")[0] + "/" + data["scene"]
    settings = data.get("settings") or {}
    if not isinstance(settings, dict):
        raise UserError(f"{args.file}: field 'settings' must be a table")
    summary = run_pack(
        ref, data["steps"], events=events, out=args.out, pack_paths=args.pack_path, dt=data["dt"], settings=settings
    )
    same = summary["digest"] == data["digest"]
    print(
        f"replayed {data['steps']} steps of {ref}: digest {summary['digest'][:16]} "
        + ("matches the recording" if same else f"DIFFERS from the recording ({data['digest'][:16]})")
    )
    return 0 if same else 1

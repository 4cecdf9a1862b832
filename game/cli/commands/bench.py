"""`chainsim bench NAME ...`: benchmarks; each is a module with add_arguments(p) and run(args)."""

from __future__ import annotations

import importlib

from chainsim.game.server import require_web_stack
from chainsim.systems.engine.errors import UserError

NAME = "bench"
HELP = "run a benchmark (chainmail, render, ...)"

# name -> module; a benchmark module is imported only to build its sub-parser
BENCHES = {
    "chainmail": "chainsim.tools.bench.chainmail",
    "render": "chainsim.tools.bench.render",
    "docs": "chainsim.tools.bench.docs",
    "window": "chainsim.tools.bench.window",
    "models": "chainsim.tools.bench.models",
    "sheet": "chainsim.tools.bench.sheet",
    "sleeping": "chainsim.tools.bench.sleeping",
    "records": "chainsim.tools.bench.records",
    "train": "chainsim.tools.bench.train",
    "needle": "chainsim.tools.bench.needle",
    "replay": "chainsim.tools.bench.replay",
    "haptics": "chainsim.tools.bench.haptics",
    "startup": "chainsim.tools.bench.startup",
}

# benchmarks that start `chainsim serve`: without the server extra they stop before starting anything
SERVES = ("records", "train")


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP)
    bsub = p.add_subparsers(dest="bench", metavar="BENCH", parser_class=type(p))
    for name, modname in BENCHES.items():
        mod = importlib.import_module(modname)
        bp = bsub.add_parser(name, help=getattr(mod, "HELP", ""))
        mod.add_arguments(bp)
        bp.set_defaults(_bench=mod.run)
    return p


def run(args) -> int:
    if not getattr(args, "_bench", None):
        raise UserError(f"name a benchmark: {', '.join(BENCHES)}")
    if args.bench in SERVES:
        require_web_stack(f"bench {args.bench}")
    return args._bench(args)

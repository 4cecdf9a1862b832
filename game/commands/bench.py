"""`chainsim bench NAME ...`: benchmarks; each is a module tools/bench_NAME.py with add_arguments(p) and run(args)."""

from __future__ import annotations

import importlib
import pkgutil

NAME = "bench"
HELP = "run a benchmark (chainmail, render, ...)"


def _benches():
    import tools

    return sorted(m.name[len("bench_"):] for m in pkgutil.iter_modules(tools.__path__) if m.name.startswith("bench_"))


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP)
    bsub = p.add_subparsers(dest="bench", metavar="BENCH", parser_class=type(p))
    for name in _benches():
        mod = importlib.import_module(f"tools.bench_{name}")
        bp = bsub.add_parser(name, help=getattr(mod, "HELP", ""))
        mod.add_arguments(bp)
        bp.set_defaults(_bench=mod.run)
    return p


def run(args) -> int:
    from game.errors import UserError

    if not getattr(args, "_bench", None):
        raise UserError(f"name a benchmark: {', '.join(_benches()) or 'none installed'}")
    return args._bench(args)

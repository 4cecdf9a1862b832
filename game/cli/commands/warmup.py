"""`chainsim warmup`: compile every numba kernel ahead (after installing), so nothing waits later.

The kernel groups compile in child processes side by side (chainsim.systems.engine.warmup.Compiler), then
this process loads them all from numba's cache, which also compiles anything a child could not.
Every kernel a built-in pack can reach on this machine is among them (warmup.reachable); `--all`
adds the rest (ChainMail in float32, the parallel kernels numba never takes with this few threads)."""

from __future__ import annotations

import time

from chainsim.systems.engine.progress import progress
from chainsim.systems.engine.warmup import GROUPS, Compiler, reachable, warm_up

NAME = "warmup"
HELP = (
    "compile every numba kernel a built-in pack can reach now (a minute or two, once per install) "
    "so nothing waits on it later"
)


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP, description=HELP)
    p.add_argument("--in-process", action="store_true", help="compile in this process only, one group after another")
    p.add_argument(
        "--all",
        action="store_true",
        help="also the kernels no built-in pack reaches on this machine (float32 ChainMail, parallel kernels "
        "numba only takes with 4 or more threads)",
    )
    return p


def run(args) -> int:
    t0 = time.perf_counter()
    groups = list(GROUPS) if getattr(args, "all", False) else reachable()
    if not getattr(args, "in_process", False):
        compiler = Compiler(groups=groups)
        bar = progress(total=compiler.total, desc="compiling kernels", unit="group")
        try:
            seen, said = 0, ""
            while not compiler.wait(0.25):
                now, busy = len(compiler.done), ", ".join(compiler.compiling())
                if busy != said:
                    bar.set_postfix_str(busy)
                    said = busy
                bar.update(now - seen)
                seen = now
            bar.update(compiler.total - seen)
        finally:
            bar.close()
        compiler.close()
    for name, why in compiler.failed.items() if not getattr(args, "in_process", False) else ():
        print(f"{name}: compiled here ({why})")
    warm_up(groups)  # loads what the children cached; compiles here whatever they could not
    print(f"kernels ready in {time.perf_counter() - t0:.1f} s")
    return 0

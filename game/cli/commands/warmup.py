"""`chainsim warmup`: compile every numba kernel ahead (after installing), so nothing waits later."""

from __future__ import annotations

import time

from chainsim.engine.warmup import warm_up

NAME = "warmup"
HELP = "compile the soft-tissue kernels now (seconds, once per install) so no interaction waits on it"


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP, description=HELP)
    return p


def run(args) -> int:
    t0 = time.perf_counter()
    warm_up()
    print(f"kernels ready in {time.perf_counter() - t0:.1f} s")
    return 0

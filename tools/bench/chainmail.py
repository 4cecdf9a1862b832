"""`chainsim bench chainmail`: Generalised ChainMail speed against the thesis (6.2) and at scale.

    chainsim bench chainmail [--quick] [--out DIR] [--exact]  thesis grids, worst case, scaling, exact limits, drags
    chainsim bench chainmail --mesh MESH --grab I --to X Y Z --alpha-min A --alpha-max B --beta C
                             [--order O] [--exact] [--repeat R] [--json]   one cascade on a mesh, from rest

The first form writes results.md, results.json and results.png to DIR (default runs/bench-chainmail)
and prints the tables; the second prints the timing (JSON with --json), with --exact the cost of the
exact-limit pass beside it, and for every waiting-list order the links a plain cascade leaves outside
their limits. Timings are medians of repeated runs after warm-up; the rest state is restored between runs
outside the timed region.
"""

from __future__ import annotations

from chainsim.systems.engine import argtypes, limits
from chainsim.systems.engine.chainmail_params import ORDER_CHOICES
from chainsim.tools.bench import run as impl

HELP = "ChainMail speed: thesis 6.2 grids and worst case, scaling to 1M elements, or one mesh (--mesh)"


def add_arguments(p) -> None:
    p.add_argument("--quick", action="store_true", help="a fast subset (smaller meshes, fewer repeats)")
    p.add_argument("--out", default="runs/bench-chainmail", metavar="DIR", help="folder for results.md/.json/.png")
    p.add_argument(
        "--repeat", type=argtypes.repeat, default=0, metavar="R", help="timed repeats per case (default: by size)"
    )
    p.add_argument(
        "--max-elements",
        type=argtypes.real(1000.0, float(limits.MAX_BENCH_ELEMENTS)),
        default=0,
        metavar="N",
        help="largest scaling mesh (default 1e6, quick 1e5)",
    )
    p.add_argument(
        "--parts",
        default="thesis,worst,scaling,exact,drag",
        help="comma-separated parts to run: thesis, worst, scaling, exact, drag, threads",
    )
    p.add_argument("--mesh", metavar="MESH", help="time one cascade on this mesh (.npz graph or mesh file)")
    p.add_argument("--grab", type=argtypes.element, metavar="I", help="(--mesh) element to move")
    p.add_argument("--to", type=argtypes.coordinate, nargs="+", metavar="X", help="(--mesh) target coordinates")
    p.add_argument(
        "--alpha-min",
        type=argtypes.real(0.0, 1.0),
        default=1.0,
        metavar="A",
        help="(--mesh) compression limit (default 1)",
    )
    p.add_argument(
        "--alpha-max", type=argtypes.real(1.0), default=1.0, metavar="B", help="(--mesh) stretch limit (default 1)"
    )
    p.add_argument("--beta", type=argtypes.real(0.0), default=0.0, metavar="C", help="(--mesh) shear limit (default 0)")
    p.add_argument(
        "--relax", type=argtypes.relax, default=0, metavar="N", help="(--mesh) relaxation sweeps after the cascade"
    )
    p.add_argument(
        "--order",
        choices=ORDER_CHOICES,
        default="breadth-first",
        help="(--mesh) waiting-list order (fifo: breadth-first)",
    )
    p.add_argument(
        "--exact",
        action="store_true",
        help="also time the exact-limit pass after each cascade (suite: run the exact part)",
    )
    p.add_argument("--json", action="store_true", help="(--mesh) print JSON only")


def run(args) -> int:
    # No wait policy of its own: the level-parallel rows run under the engine's
    # (chainsim.systems.engine.threads: idle workers sleep at once unless the caller sets OMP_WAIT_POLICY,
    # GOMP_SPINCOUNT, KMP_BLOCKTIME or NUMBA_THREADING_LAYER), the one a body's cascade runs under, so
    # they time the cascade a body gets: each wave wakes the workers again, and no idle worker takes a
    # core from the serial kernels timed next. GOMP_SPINCOUNT=20000 (tens of microseconds, what this
    # bench used to set) keeps them awake from one wave to the next instead, the cascade's best case on a
    # quiet machine (waves.AUTO_STEPS was measured with libgomp's own spin, 3 ms); on a busy machine a
    # spinning worker takes turns with the one still working.
    if args.mesh:
        return impl.run_mesh(args)
    return impl.run_suite(args)

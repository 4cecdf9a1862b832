"""Where the level-parallel cascade beats the serial breadth-first one: soft drags by size and thread count.

The figures behind `chainsim.systems.engine.kernels.waves.parallel_wins`. For tet blocks of about 10k, 100k and 1M
elements (meshgen.tet_grid: 22^3, 47^3, 100^3) and each thread count (numba.set_num_threads), the centre
element is dragged 12 frames, one rest spacing further each frame along a slanted direction, every frame
from the last one's shape, on a soft material (alpha 0.85 / 1.15, beta 0.1): the `drag` rows of
`chainsim bench chainmail`. The serial breadth-first cascade (`cascade(..., parallel=False)`) and the
level-parallel one (`parallel=True`) each drag their own copy of the block, frame by frame in alternation,
so a busy machine loads both alike; one untimed drag first compiles and warms, then the medians over every
frame of the timed drags. Both must end in the same shape (the level-parallel result is the serial one bit
for bit).

Standalone on purpose: it imports only numpy, numba, scipy (kernels.graph) and chainsim.systems.engine's kernels and
meshgen, never the app, so it runs from a bare checkout. Without an installed chainsim it maps the package
onto this checkout's folders itself (a temporary `chainsim/engine` link to systems/engine).

    python tools/bench/crossover.py [--sizes 22,47,100] [--threads 1,2,4,8,16] [--repeats 2] [--out DIR]

prints a markdown table and, with --out, writes it (crossover.md) and the rows (crossover.json) there.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
FRAMES = 12
MATERIAL = (0.85, 1.15, 0.1)
DIRECTION = (0.3, 0.5, 0.8)


def _import_engine():
    """chainsim.systems.engine from this checkout: through a temporary package folder when chainsim is not installed."""
    try:
        importlib.import_module("chainsim.systems.engine.kernels.chainmail")
    except ImportError:
        pkg = Path(tempfile.mkdtemp(prefix="chainsim-pkg-")) / "chainsim"
        pkg.mkdir()
        (pkg / "__init__.py").write_text("")
        (pkg / "systems").mkdir()
        (pkg / "systems" / "__init__.py").write_text("")
        (pkg / "systems" / "engine").symlink_to(ROOT / "systems" / "engine", target_is_directory=True)
        sys.path.insert(0, str(pkg.parent))
        for name in [m for m in sys.modules if m == "chainsim" or m.startswith("chainsim.")]:
            del sys.modules[name]
    names = (
        "chainsim.systems.engine.meshgen",
        "chainsim.systems.engine.kernels.chainmail",
        "chainsim.systems.engine.kernels.graph",
    )
    return (
        *(importlib.import_module(m) for m in names),
        importlib.import_module("chainsim.systems.engine.kernels.waves"),
    )


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def measure(side: int, thread_counts: list[int], repeats: int, modules) -> list[dict]:
    meshgen, chainmail, graph_mod, waves = modules
    t0 = time.perf_counter()
    rest, _tets, links = meshgen.tet_grid(side, side, side)
    n = len(rest)
    graph = graph_mod.build_graph(n, links)
    mats = chainmail.material_arrays(graph.n_links, *MATERIAL)
    grab = np.array([int(np.argmin(np.sum((rest - rest.mean(axis=0)) ** 2, axis=1)))])
    direction = np.asarray(DIRECTION) / np.linalg.norm(DIRECTION)
    targets = rest[grab[0]] + np.arange(1, FRAMES + 1)[:, None] * 1.0 * direction  # tet_grid spacing 1
    _log(f"{n:,} elements, {graph.n_links:,} links (built in {time.perf_counter() - t0:.1f} s)")
    rows = []
    previous = numba.get_num_threads()
    try:
        for threads in thread_counts:
            numba.set_num_threads(threads)
            pos = {False: rest.copy(), True: rest.copy()}
            ws = {False: chainmail.make_workspace(n), True: chainmail.make_workspace(n)}
            times: dict[bool, list[float]] = {False: [], True: []}
            moved = {False: 0, True: 0}
            t_row = time.perf_counter()
            for rep in range(repeats + 1):  # drag 0 compiles and warms
                for p in pos.values():
                    np.copyto(p, rest)
                for f in range(FRAMES):
                    for parallel in (False, True):
                        t = time.perf_counter()
                        order, _ = chainmail.cascade(
                            rest, pos[parallel], graph, *mats, grab, targets[f : f + 1], workspace=ws[parallel],
                            copy=False, parallel=parallel,
                        )  # fmt: skip
                        dt = time.perf_counter() - t
                        if rep:
                            times[parallel].append(dt)
                        moved[parallel] = len(order)
            same = bool(np.array_equal(pos[False], pos[True]))
            serial = statistics.median(times[False]) * 1e3
            par = statistics.median(times[True]) * 1e3
            row = {
                "elements": n,
                "threads": threads,
                "serial_ms": serial,
                "parallel_ms": par,
                "speedup": serial / par,
                "moved_last": moved[False],
                "same_result": same,
                "rule_picks_parallel": waves.parallel_wins(n, threads),
            }
            rows.append(row)
            _log(
                f"  {n:9,d} elements {threads:2d} threads: serial {serial:9.3f} ms  level-parallel {par:9.3f} ms  "
                f"{row['speedup']:5.2f}x  moved {moved[False]:,}  same {same}  "
                f"({time.perf_counter() - t_row:.1f} s)"
            )
    finally:
        numba.set_num_threads(previous)
    return rows


def describe() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (
        f"{cpu}, {os.cpu_count()} logical CPUs, numba {numba.__version__} ({numba.config.NUMBA_NUM_THREADS} threads), "
        f"numpy {np.__version__}, Python {platform.python_version()}; load {load:.1f} at the start"
    )


def markdown(rows: list[dict], header: str) -> str:
    out = [
        header,
        "",
        "| elements | threads | serial ms | level-parallel ms | speed-up | moved (last frame) | same result "
        "| rule picks |",
        "|---:|---:|---:|---:|---:|---:|---|---|",
    ]
    for r in rows:
        pick = "level-parallel" if r["rule_picks_parallel"] else "serial"
        out.append(
            f"| {r['elements']:,} | {r['threads']} | {r['serial_ms']:.3f} | {r['parallel_ms']:.3f} | "
            f"{r['speedup']:.2f}x | {r['moved_last']:,} | {'yes' if r['same_result'] else 'NO'} | {pick} |"
        )
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="22,47,100", help="block sides (elements = side^3), comma separated")
    ap.add_argument("--threads", default="1,2,4,8,16", help="thread counts; those above numba's are left out")
    ap.add_argument("--repeats", type=int, default=2, help="timed drags of 12 frames after the warm-up drag")
    ap.add_argument("--out", default=None, help="folder for crossover.md and crossover.json (written after each row)")
    args = ap.parse_args(argv)
    modules = _import_engine()
    top = numba.config.NUMBA_NUM_THREADS
    wanted = [int(t) for t in args.threads.split(",")]
    counts = [t for t in wanted if t <= top]
    if len(counts) < len(wanted):
        _log(f"numba has {top} threads: leaving out {[t for t in wanted if t > top]}")
    header = (
        f"Soft drags ({FRAMES} frames, alpha {MATERIAL[0]}/{MATERIAL[1]}, beta {MATERIAL[2]}), medians of "
        f"{FRAMES * args.repeats} frames after a warm-up drag. {describe()}."
    )
    _log(header)
    out = Path(args.out) if args.out else None
    if out:
        out.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    t0 = time.perf_counter()
    for side in [int(s) for s in args.sizes.split(",")]:
        rows += measure(side, counts, args.repeats, modules)
        if out:
            (out / "crossover.md").write_text(markdown(rows, header))
            (out / "crossover.json").write_text(json.dumps({"header": header, "rows": rows}, indent=1))
    try:
        layer = f"numba threading layer {numba.threading_layer()}. "
    except ValueError:  # no parallel region ran
        layer = ""
    print(markdown(rows, header + f" {layer}Whole run {time.perf_counter() - t0:.0f} s."))
    return 0 if all(r["same_result"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())

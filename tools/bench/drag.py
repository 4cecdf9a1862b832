"""The drag rows of `chainsim bench chainmail`: ChainMail as a tool uses it, beside the lean cascade.

A drag is what every interaction does: one element is grabbed and moved a little further each frame,
each frame's cascade starting from the shape the last one left. So a row here is a 12-frame drag of
the centre element of a tet block (one rest spacing further every frame, along a slanted direction),
through the public `ChainMailBody.move`, on a soft material from the presets (assets/presets/
materials.toml; cascade only, relaxation off, since the lean cascade has none), in float64 and float32.
Beside it, frame by frame in alternation, the lean float64 FIFO cascade (chainsim.systems.engine.kernels.lean)
drags its own copy of the block through the same targets, so both see the same frames and a busy
machine loads both alike. The figures are medians over every frame of every repeat.

The `threads` part times the level-parallel cascade (kernels.waves) against the serial breadth-first one
on the same drags for each thread count numba has, and prints what `waves.parallel_wins` decides for
each size and count: the crossover the rule was set from.
"""

from __future__ import annotations

import statistics
import sys
import time
import tomllib
from importlib import resources

import numba
import numpy as np

from chainsim.systems.engine.bodies.chainmail import ChainMailBody
from chainsim.systems.engine.kernels import waves
from chainsim.systems.engine.kernels.chainmail import cascade, make_workspace, material_arrays
from chainsim.systems.engine.kernels.graph import build_graph
from chainsim.systems.engine.kernels.lean import LeanWorkspace, lean_move
from chainsim.tools.bench.meshes import tet_cube

FRAMES = 12
#: the soft materials of the presets a drag row uses (bone-like and medium barely move: a pull there is
#: nearly a rigid translation, which the scaling part already times)
PRESETS = ("soft-tissue", "very-soft")
DIRECTION = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])


def _log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def preset(name: str) -> tuple[float, float, float]:
    """(alpha_min, alpha_max, beta) of a material preset in assets/presets/materials.toml."""
    text = resources.files("chainsim.assets").joinpath("presets", "materials.toml").read_text(encoding="utf-8")
    t = tomllib.loads(text)[name]
    return float(t["alpha_min"]), float(t["alpha_max"]), float(t["beta"])


def sizes(max_elements: float) -> list[int]:
    """100k (47^3) and 1M (100^3) elements, as far as --max-elements allows; below 100k, that one size."""
    out = [n for n in (103_823, 1_000_000) if n <= max_elements * 1.05]
    return out or [int(max_elements)]


def drag_targets(rest: np.ndarray, grab: int) -> np.ndarray:
    spacing = float(np.min(np.linalg.norm(rest[1:] - rest[:-1], axis=1)))
    return rest[grab] + np.arange(1, FRAMES + 1)[:, None] * spacing * DIRECTION


def drag_row(rest, links, name: str, dtype, repeats: int) -> dict:
    """Median frame times of the body's drag and of the lean cascade's on the same frames."""
    amin, amax, beta = preset(name)
    body = ChainMailBody(rest, links, amin, amax, beta, dtype=dtype)
    graph = body.graph
    grab = int(np.argmin(np.sum((rest - rest.mean(axis=0)) ** 2, axis=1)))
    targets = drag_targets(rest, grab)
    lean_rest = np.ascontiguousarray(rest, dtype=np.float64)
    lean_pos = lean_rest.copy()
    lws = LeanWorkspace(len(rest))
    ids = np.array([grab])
    t_body, t_lean, c_body, c_lean = [], [], [], []
    moved = lean_moved = 0
    for rep in range(repeats + 1):  # the first drag warms caches and compiles
        body.reset()
        np.copyto(lean_pos, lean_rest)
        for f in range(FRAMES):
            c0 = time.process_time()
            t0 = time.perf_counter()
            changed = body.move(ids, targets[f : f + 1])
            t1 = time.perf_counter()
            c1 = time.process_time()
            lean_moved = lean_move(
                lean_rest, lean_pos, graph.indptr, graph.indices, grab, targets[f], amin, amax, beta, lws
            )
            t2 = time.perf_counter()
            c2 = time.process_time()
            if rep:
                t_body.append(t1 - t0)
                t_lean.append(t2 - t1)
                c_body.append(c1 - c0)
                c_lean.append(c2 - c1)
            moved = len(changed)
    row = {
        "material": name,
        "alpha": [amin, amax, beta],
        "elements": len(rest),
        "dtype": np.dtype(dtype).name,
        "frames": FRAMES,
        "repeats": repeats,
        "moved_last": moved,
        "lean_moved_last": int(lean_moved),
        "body_ms": statistics.median(t_body) * 1e3,
        "lean_ms": statistics.median(t_lean) * 1e3,
        "body_cpu_ms": statistics.median(c_body) * 1e3,
        "lean_cpu_ms": statistics.median(c_lean) * 1e3,
    }
    row["ratio"] = row["body_ms"] / row["lean_ms"]
    row["cpu_ratio"] = row["body_cpu_ms"] / max(row["lean_cpu_ms"], 1e-9)
    if dtype == np.float64:  # same algorithm, same arithmetic: the same shape
        row["same_as_lean"] = bool(np.array_equal(body.positions, lean_pos))
    return row


def drag_part(quick: bool, repeat: int, max_elements: float) -> list[dict]:
    rows = []
    for n in sizes(max_elements):
        rest, _cells, links = tet_cube(n)
        reps = repeat or (2 if quick else (5 if len(rest) < 500_000 else 3))
        _log(f"  drag: tet block of {len(rest)} elements, {FRAMES} frames x {reps} repeats")
        for name in PRESETS:
            for dtype in (np.float64, np.float32):
                row = drag_row(rest, links, name, dtype, reps)
                rows.append(row)
                _log(
                    f"    {name:12s} {row['dtype']}: {row['body_ms']:.3f} ms a frame, lean {row['lean_ms']:.3f} ms, "
                    f"ratio {row['ratio']:.2f} (cpu {row['cpu_ratio']:.2f}); {row['moved_last']} moved in the last"
                )
    return rows


def _thread_counts() -> list[int]:
    top = numba.config.NUMBA_NUM_THREADS
    out = [t for t in (1, 2, 4, 8, 16, 32, 64) if t <= top]
    return out if top in out else [*out, top]


def threads_part(quick: bool, repeat: int, max_elements: float) -> list[dict]:
    """Serial and level-parallel breadth-first cascades on the same soft drags, by size and thread count."""
    rows = []
    amin, amax, beta = preset("soft-tissue")
    for n in [s for s in (10_648, 103_823, 1_000_000) if s <= max_elements * 1.05] or [int(max_elements)]:
        rest, _cells, links = tet_cube(n)
        n = len(rest)
        graph = build_graph(n, links)
        mats = material_arrays(graph.n_links, amin, amax, beta)
        grab = np.array([int(np.argmin(np.sum((rest - rest.mean(axis=0)) ** 2, axis=1)))])
        targets = drag_targets(rest, int(grab[0]))
        reps = repeat or (2 if quick else 3)
        previous = numba.get_num_threads()
        try:
            for threads in _thread_counts():
                numba.set_num_threads(threads)
                times = {}
                for parallel in (False, True):
                    pos = rest.copy()
                    ws = make_workspace(n)
                    ts = []
                    for rep in range(reps + 1):
                        np.copyto(pos, rest)
                        for f in range(FRAMES):
                            t0 = time.perf_counter()
                            cascade(rest, pos, graph, *mats, grab, targets[f : f + 1], workspace=ws, copy=False,
                                    parallel=parallel)  # fmt: skip
                            if rep:
                                ts.append(time.perf_counter() - t0)
                    times[parallel] = statistics.median(ts) * 1e3
                row = {
                    "elements": n,
                    "threads": threads,
                    "serial_ms": times[False],
                    "parallel_ms": times[True],
                    "speedup": times[False] / times[True],
                    "rule_picks_parallel": waves.parallel_wins(n, threads),
                }
                rows.append(row)
                _log(
                    f"    {n:8d} elements, {threads:2d} threads: serial {row['serial_ms']:.3f} ms, level-parallel "
                    f"{row['parallel_ms']:.3f} ms ({row['speedup']:.2f}x); rule picks "
                    f"{'level-parallel' if row['rule_picks_parallel'] else 'serial'}"
                )
        finally:
            numba.set_num_threads(previous)
    return rows


def markdown(results: dict) -> list[str]:
    out = []
    if results.get("drag"):
        out.append("## Drags: soft presets through ChainMailBody.move, beside the lean cascade\n")
        out.append(
            f"The centre element of a tet block dragged {FRAMES} frames, one rest spacing further each frame, every "
            "frame from the last one's shape (cascade only, breadth-first). Lean: the lean float64 FIFO cascade "
            "(chainsim.systems.engine.kernels.lean) on the same frames, timed alternately with the body frame by "
            "frame. "
            "Medians over every frame of every repeat; ratio = body / lean (wall clock; CPU time in brackets).\n"
        )
        out.append("| material | elements | positions | body ms | lean ms | ratio | moved (last frame) |")
        out.append("|---|---:|---|---:|---:|---:|---:|")
        for r in results["drag"]:
            out.append(
                f"| {r['material']} | {r['elements']:,} | {r['dtype']} | {r['body_ms']:.3f} | {r['lean_ms']:.3f} | "
                f"{r['ratio']:.2f} ({r['cpu_ratio']:.2f}) | {r['moved_last']:,} |"
            )
        out.append("")
    if results.get("threads"):
        out.append("## Level-parallel against serial breadth-first cascade, by size and thread count\n")
        out.append(
            f"Soft-tissue drags as above ({FRAMES} frames), through `cascade(..., parallel=...)`; medians. Rule: what "
            "`chainsim.systems.engine.kernels.waves.parallel_wins` picks for that size and thread count.\n"
        )
        out.append("| elements | threads | serial ms | level-parallel ms | speed-up | rule picks |")
        out.append("|---:|---:|---:|---:|---:|---|")
        for r in results["threads"]:
            pick = "level-parallel" if r["rule_picks_parallel"] else "serial"
            out.append(
                f"| {r['elements']:,} | {r['threads']} | {r['serial_ms']:.3f} | {r['parallel_ms']:.3f} | "
                f"{r['speedup']:.2f}x | {pick} |"
            )
        out.append("")
    return out

"""`chainsim bench sleeping`: what a local pull costs on a small and a large body when far nodes sleep.

"Model only what a scene requires": a tool that pulls a 6 mm patch of a tissue slab disturbs the
tissue near it; the rest need not be solved every frame. The hybrid body (systems/engine/bodies/hybrid.py)
sleeps nodes whose neighbours barely move and wakes them when the disturbance reaches them. This
benchmark drags the same patch the same way on slabs of the same tissue, the same 1.25 mm tetrahedra
and the same 20 mm depth, only wider (30 mm: ~10k nodes; 100 mm: ~110k nodes), with sleeping on and
off, and reports:

- the CPU per frame (median over the drag and hold, one thread) of each, and the large slab's over the
  small slab's: the cost of a body that is ten times bigger around the same pull;
- the nodes a frame solves (the awake region);
- the extra error that sleeping brings: the sleeping body's shape against the same body solved whole
  on the same frames, RMS over all nodes and the worst node, as a fraction of the lift; and relative to
  the displacement field, |u_sleeping - u_whole| / |u_whole| over all nodes. The RMS over all nodes is
  diluted by every node far from the pull: with sleepers held where they were, on the 111k-node slab it
  read 1.4 % where the field-relative difference was 27 %, since the whole body's far field (each node
  moving less than the sleep threshold, but a hundred thousand of them) was what they left out. The
  sleepers now follow the far field (systems/engine/bodies/far_field.py), and the figure is what shows it.

The pull: the patch rises `--lift` mm (or, with `--side`, moves that far sideways) over `--ramp` frames
(a drag, a new target every frame) and is held for `--hold` frames. Frames at 60 Hz; the first frame
after the grab (the awake region's first factorisation) and the slowest frame are reported apart, since
they are the pauses a user could feel.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

import numba
import numpy as np

from chainsim.systems.engine.argtypes import count, real
from chainsim.systems.engine.bodies.hybrid import HybridBody
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.progress import progress
from chainsim.tools.study import surgical

HELP = "a local pull on a 10k- and a 110k-node slab with and without sleeping: ms per frame, awake nodes, error"
DEPTH_MM, PATCH_MM = surgical.BLOCK_MM[2], surgical.PATCH_MM
SETTING: dict[str, Any] = dict(start="linear", cg_iterations=3, rotation_iterations=2)


def add_arguments(p) -> None:
    p.add_argument("--widths", default="30,100", help="slab widths in mm, comma-separated (10..150; default 30,100)")
    p.add_argument("--element-mm", type=real(0.8, 5.0), default=1.25, help="tetrahedron edge in mm (0.8..5)")
    p.add_argument("--E", type=real(1e3, 1e6), default=3e4, help="Young's modulus in Pa (1e3..1e6)")
    p.add_argument("--nu", type=real(0.0, 0.499), default=0.45, help="Poisson's ratio (0..0.499)")
    p.add_argument("--sleep", type=real(1e-4, 0.5), default=0.015, help="sleep threshold (of the lift)")
    p.add_argument("--lift", type=real(0.1, 10.0), default=3.0, help="how far the patch rises, mm")
    p.add_argument("--ramp", type=count(1, 600), default=12, help="frames over which the patch rises")
    p.add_argument("--hold", type=count(0, 600), default=18, help="frames the lift is held")
    p.add_argument("--side", action="store_true", help="move the patch sideways (x) by --lift mm instead of up")
    p.add_argument("--out", default="runs/bench-sleeping", help="folder for results.json and results.md")


def slab(width: float, element: float):
    """A width x width x 20 mm slab fixed at the bottom, with the study's 6 mm square patch at the top
    centre: the surgical study's block (chainsim.tools.study.surgical.block), only wider."""
    b = surgical.block(element, (width, width, DEPTH_MM))
    return b.pos, b.tets, b.fixed, b.grabbed


def _widths(text: str) -> list[float]:
    try:
        out = [float(w) for w in text.split(",") if w.strip()]
    except ValueError:
        out = []
    if not out or not all(10.0 <= w <= 150.0 for w in out):
        raise UserError(f"--widths: expected slab widths of 10..150 mm separated by commas, got {text!r}")
    return out


def drag(body: HybridBody, pos: np.ndarray, patch: np.ndarray, lifts: np.ndarray, desc: str, side: bool = False):
    """Step the pull frame by frame (up, or along x with `side`); CPU seconds, nodes solved and the shape
    after each frame."""
    times, solved, shapes = [], [], []
    axis = np.array([1.0, 0.0, 0.0]) if side else np.array([0.0, 0.0, 1.0])
    for lift in progress(lifts, desc=desc, unit="frame"):
        body.grab(patch, pos[patch] + float(lift) * axis)
        t0 = time.thread_time()
        stats = body.step(1 / 60)
        times.append(time.thread_time() - t0)
        solved.append(int(stats.extra.get("solved", len(pos))))
        shapes.append(body.positions.copy())
    return np.array(times), np.array(solved), shapes


def measure(width: float, args, lifts: np.ndarray) -> dict:
    pos, tets, fixed, patch = slab(width, args.element_mm)
    runs = {}
    for name, sleep in (("sleeping", args.sleep), ("whole", 0.0)):
        body = HybridBody(pos, tets, E=args.E, nu=args.nu, fixed=fixed, unit=1e-3, sleep=sleep, **SETTING)
        runs[name] = drag(body, pos, patch, lifts, f"{width:g} mm slab, {name}", args.side)
    (ts, ns, xs), (tw, _, xw) = runs["sleeping"], runs["whole"]
    # the error sleeping adds: against the same body solved whole on the same frames, per frame
    rms = [float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1)))) / lift for a, b, lift in zip(xs, xw, lifts)]
    worst = [float(np.sqrt(np.max(np.sum((a - b) ** 2, axis=1)))) / lift for a, b, lift in zip(xs, xw, lifts)]
    field = [float(np.linalg.norm(a - b)) / max(float(np.linalg.norm(b - pos)), 1e-300) for a, b in zip(xs, xw)]
    return {
        "width_mm": width,
        "nodes": len(pos),
        "ms_sleeping": 1e3 * float(np.median(ts[1:])),
        "ms_whole": 1e3 * float(np.median(tw[1:])),
        "first_frame_ms_sleeping": 1e3 * float(ts[0]),
        "slowest_frame_ms_sleeping": 1e3 * float(ts.max()),
        "solved_median": int(np.median(ns)),
        "solved_max": int(ns.max()),
        "extra_rms_end": rms[-1],
        "extra_rms_worst_frame": max(rms),
        "extra_worst_node": max(worst),
        "extra_field_end": field[-1],
        "extra_field_worst_frame": max(field),
        "extra_field_per_frame": field,  # the first frames of a grab lag; the later ones show what stays
    }


def run(args) -> int:
    widths = _widths(args.widths)
    numba.set_num_threads(1)  # the cost of one frame on one core: the figure that scales with the body
    lifts = np.concatenate([np.arange(1, args.ramp + 1) * args.lift / args.ramp, np.full(args.hold, args.lift)])
    # compile the kernels on a small slab first so no timing holds a compilation
    pos, tets, fixed, patch = slab(10.0, 2.5)
    warm = HybridBody(pos, tets, E=args.E, nu=args.nu, fixed=fixed, unit=1e-3, sleep=args.sleep, **SETTING)
    drag(warm, pos, patch, lifts[:3], "compiling")
    rows = [measure(w, args, lifts) for w in widths]
    small = rows[0]
    for r in rows:
        r["cost_over_smallest_sleeping"] = r["ms_sleeping"] / small["ms_sleeping"]
        r["cost_over_smallest_whole"] = r["ms_whole"] / small["ms_whole"]
    info = {
        "load_average": os.getloadavg(),
        "element_mm": args.element_mm,
        "E": args.E,
        "nu": args.nu,
        "sleep": args.sleep,
        "lift_mm": args.lift,
        "side": args.side,
        "ramp": args.ramp,
        "hold": args.hold,
        "rows": rows,
    }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "results.json").write_text(json.dumps(info, indent=1))
    md = [
        f"A {PATCH_MM:g} mm patch on slabs {DEPTH_MM:g} mm deep of {args.element_mm:g} mm tetrahedra (E = {args.E:g} "
        f"Pa, nu = {args.nu:g}) {'moved sideways' if args.side else 'lifted'} {args.lift:g} mm over {args.ramp} "
        f"frames and held {args.hold}; hybrid body "
        f"(linear start, CG 3, 2 rotations), sleep {args.sleep:g}, one thread, load average "
        f"{info['load_average'][0]:.1f}. ms/frame: median CPU of every frame after the first. Extra error: the "
        "sleeping body against the same body solved whole: RMS over all nodes and the worst node as a fraction "
        "of the lift, and relative to the displacement field (|u_sleeping - u_whole| / |u_whole|).",
        "",
        "| slab | nodes | ms/frame sleeping | x smallest | ms/frame whole | x smallest | first / slowest frame ms "
        "(sleeping) | nodes solved (median, most) | extra error RMS at end (worst frame) | worst node | "
        "relative to the field at end (worst frame) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        md.append(
            f"| {r['width_mm']:g} mm | {r['nodes']} | {r['ms_sleeping']:.1f} | "
            f"{r['cost_over_smallest_sleeping']:.2f} | "
            f"{r['ms_whole']:.1f} | {r['cost_over_smallest_whole']:.2f} | {r['first_frame_ms_sleeping']:.0f} / "
            f"{r['slowest_frame_ms_sleeping']:.0f} | {r['solved_median']}, {r['solved_max']} | "
            f"{100 * r['extra_rms_end']:.2f} % ({100 * r['extra_rms_worst_frame']:.2f} %) | "
            f"{100 * r['extra_worst_node']:.1f} % | "
            f"{100 * r['extra_field_end']:.1f} % ({100 * r['extra_field_worst_frame']:.1f} %) |"
        )
    (out / "results.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return 0

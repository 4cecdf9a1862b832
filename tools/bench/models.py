"""`chainsim bench models`: XPBD and projective dynamics on the study's block at about 10k nodes.

For each model and setting: CPU per frame (median, one thread), and how many 60 Hz frames after a
10 % pull it takes from rest to come within 5 % RMS (error / imposed displacement) of the reference:
linear FEM on this mesh plus the nonlinear correction of neo-Hookean FEM on a coarse mesh (the
study's composite reference). Bounded: at most --frames frames per run.
"""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path

import numba
import numpy as np

from chainsim.engine.bodies.projective import ProjectiveBody
from chainsim.engine.bodies.xpbd import XPBDBody
from chainsim.engine.errors import UserError
from chainsim.engine.progress import progress
from chainsim.tools.study import scenes as sc
from chainsim.tools.study.fem_linear import LinearFEM
from chainsim.tools.study.fem_nonlinear import solve_neohookean
from chainsim.tools.study.metrics import displacement_error

HELP = "XPBD and projective dynamics at ~10k nodes: ms per frame and frames to 5 % of the reference"
logger = logging.getLogger(__name__)
E, NU, STRAIN, TARGET = 3000.0, 0.45, 0.1, 0.05

SETTINGS = {
    "xpbd, 1 substep": lambda s: XPBDBody(s.pos, s.tets, E=E, nu=NU, damping=0.1, substeps=1, fixed=s.fixed),
    "xpbd, 2 substeps": lambda s: XPBDBody(s.pos, s.tets, E=E, nu=NU, damping=0.1, substeps=2, fixed=s.fixed),
    "projective statics, 1 iteration": lambda s: ProjectiveBody(
        s.pos, s.tets, E=E, nu=NU, iterations=1, dynamic=False, fixed=s.fixed
    ),
    "projective statics, 3 iterations": lambda s: ProjectiveBody(
        s.pos, s.tets, E=E, nu=NU, iterations=3, dynamic=False, fixed=s.fixed
    ),
}


def add_arguments(p) -> None:
    p.add_argument("--n", type=int, default=22, help="nodes per block edge (22: 10,648 nodes)")
    p.add_argument("--frames", type=int, default=600, help="most frames per run (bounded)")
    p.add_argument("--out", default="runs/bench-models", help="folder for results.json and results.md")


def reference(n: int):
    coarse, fine = sc.block(7), sc.block(n)
    nl = solve_neohookean(coarse.pos, coarse.tets, E, NU, coarse.constrained, coarse.constrained_disp(STRAIN))
    lin_c = LinearFEM(coarse.pos, coarse.tets, E, NU, coarse.constrained).solve(coarse.constrained_disp(STRAIN)).u
    lin_f = LinearFEM(fine.pos, fine.tets, E, NU, fine.constrained).solve(fine.constrained_disp(STRAIN)).u
    return fine, lin_f + coarse.interpolate(nl.u[1.0] - lin_c, fine.pos)


def run(args) -> int:
    if not (4 <= args.n <= 60):
        raise UserError(f"--n: expected 4..60 nodes per edge, got {args.n}")
    if not (1 <= args.frames <= 100_000):
        raise UserError(f"--frames: expected 1..100000, got {args.frames}")
    numba.set_num_threads(1)
    scene, ref = reference(args.n)
    d = STRAIN * scene.length
    rows = []
    for name, make in SETTINGS.items():
        warm = make(scene)
        warm.grab(scene.grabbed, scene.pos[scene.grabbed] + scene.grab_disp(STRAIN))
        warm.step(1 / 60)  # compilation and factorisation outside the timing
        body = make(scene)
        body.grab(scene.grabbed, scene.pos[scene.grabbed] + scene.grab_disp(STRAIN))
        times, reached, err = [], None, None
        for f in progress(range(1, args.frames + 1), desc=name, unit="frame"):
            t0 = time.thread_time()
            body.step(1 / 60)
            times.append(time.thread_time() - t0)
            if f % 5 == 0 or f < 10:
                err = displacement_error(body.positions - scene.pos, ref, d)[0]
                if err <= TARGET:
                    reached = f
                    break
        rows.append(
            {
                "setting": name,
                "nodes": scene.n_nodes,
                "ms_per_frame_median": 1e3 * float(np.median(times[1:] or times)),
                "first_frame_ms": 1e3 * times[0],
                "frames_to_5_percent": reached,
                "rms_error_at_end": err,
            }
        )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    info = {"load_average": os.getloadavg(), "nodes": scene.n_nodes, "rows": rows}
    (out / "results.json").write_text(json.dumps(info, indent=1))
    md = [
        f"Block of {scene.n_nodes} nodes, 10 % pull, one thread, load average {info['load_average'][0]:.1f}.",
        "",
        "| setting | ms/frame (median) | frames to 5 % RMS | RMS at end |",
        "|---|---:|---:|---:|",
    ]
    for r in rows:
        reached = r["frames_to_5_percent"] or f"not within {args.frames}"
        md.append(f"| {r['setting']} | {r['ms_per_frame_median']:.1f} | {reached} | {r['rms_error_at_end']:.3f} |")
    (out / "results.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return 0

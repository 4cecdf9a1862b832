"""`chainsim bench models`: XPBD and projective dynamics at about 10k nodes, on tissue where it lives
(the surgical-scale study's 30 x 30 x 20 mm block of 1.25 mm tetrahedra, E from --E) or on the
speed-accuracy study's 1 m block (--scene block).

For each model and setting, two phases on one body: a 10 % pull from rest, then (once within 5 %)
a further pull of 5 % of the block's height from that converged state, the interactive case of a
tool that keeps moving. Reported per phase: how many 60 Hz frames it takes to come within 5 % RMS
(error / imposed displacement) of the reference; the time per frame of the warm phase (median; one
thread's CPU time, or with --threads each setting on one thread and then on N, all by the wall clock,
with the process's CPU time beside, while --busy processes, 2 unless told, keep cores busy; then a tool
that moves every frame, one thread and N taking turns); and the active region (the nodes a frame
solves: every free node, unless the body sleeps far from the tool). The reference: on the tissue
block, neo-Hookean P1 FEM on the same mesh; on the 1 m block, linear FEM on this mesh plus the
nonlinear correction of neo-Hookean FEM on a coarse mesh. Bounded: at most --frames frames per phase.
`--parts long` runs the tissue block's holds, drags and far pulls of tools/study/long_runs.py instead (or
as well, with `--parts settle,long`); `--parts stiffness` its held lift at four stiffnesses.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numba
import numpy as np

from chainsim.systems.engine import argtypes
from chainsim.systems.engine.bodies.hybrid import HybridBody
from chainsim.systems.engine.bodies.projective import ProjectiveBody
from chainsim.systems.engine.bodies.xpbd import XPBDBody
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.progress import progress
from chainsim.systems.engine.threads import describe as wait_policy
from chainsim.tools.study import scenes as sc
from chainsim.tools.study import surgical
from chainsim.tools.study.fem_linear import LinearFEM
from chainsim.tools.study.fem_nonlinear import solve_neohookean
from chainsim.tools.study.long_runs import bench as bench_long_runs
from chainsim.tools.study.long_runs import bench_stiffness
from chainsim.tools.study.long_runs import parts as parse_parts
from chainsim.tools.study.metrics import displacement_error

HELP = "XPBD and projective dynamics at ~10k nodes: ms per frame and frames to 5 % of the reference"
logger = logging.getLogger(__name__)
E, NU, STRAIN, STEP, TARGET = 3000.0, 0.45, 0.1, 0.05, 0.05
BUDGET_MS = 10.0  # the frame budget the report measures each setting against
MAX_BUSY = 64  # most processes --busy starts
# --threads: frames of a tool that moves every frame (by JIGGLE of the block's height: 0.05 mm on the
# tissue block) timed on each thread count, beside the phases, which may be a frame or two long
MOVING_FRAMES, JIGGLE = 40, 0.0025


def _pd(**kw):
    return lambda s: ProjectiveBody(s.pos, s.tets, E=s.E, nu=s.nu, dynamic=False, fixed=s.fixed, unit=s.unit, **kw)


def _xpbd(substeps):
    return lambda s: XPBDBody(s.pos, s.tets, E=s.E, nu=s.nu, damping=0.1, substeps=substeps, fixed=s.fixed, unit=s.unit)


def _hybrid(**kw):
    return lambda s: HybridBody(s.pos, s.tets, E=s.E, nu=s.nu, fixed=s.fixed, unit=s.unit, **kw)


SETTINGS = {
    "xpbd, substeps by rule": _xpbd("auto"),
    "xpbd, 1 substep": _xpbd(1),
    "xpbd, 2 substeps": _xpbd(2),
    "projective statics, direct, 1 iteration": _pd(iterations=1, rotation_iterations=1),
    "projective statics, CG 6, 1 iteration": _pd(iterations=1, solver="cg", cg_iterations=6, rotation_iterations=1),
    "projective statics, CG 10, 1 iteration": _pd(iterations=1, solver="cg", cg_iterations=10, rotation_iterations=1),
    "projective statics, CG 20, 1 iteration": _pd(iterations=1, solver="cg", cg_iterations=20, rotation_iterations=1),
    "hybrid, ChainMail start, CG 6": _hybrid(coarse=0.0, start="chainmail", cg_iterations=6, rotation_iterations=1),
    "hybrid, coarse 3 edges, CG 6, 3 rotations": _hybrid(start="none", cg_iterations=6, rotation_iterations=3),
    "hybrid, linear start, CG 6, 3 rotations": _hybrid(start="linear", cg_iterations=6, rotation_iterations=3),
    "hybrid, linear start, CG 3, 2 rotations": _hybrid(start="linear", cg_iterations=3, rotation_iterations=2),
    "hybrid, linear start, CG 3, 2 rotations, sleeping 0.015": _hybrid(
        start="linear", cg_iterations=3, rotation_iterations=2, sleep=0.015, wake_rings=4
    ),
}


class TissueScene:
    """The surgical study's block as the bench's scene: a lift of `strain` x 20 mm at the top patch."""

    def __init__(self, element_mm: float, E_: float, nu: float):
        self.b = surgical.block(element_mm)
        self.pos, self.tets, self.fixed, self.grabbed = self.b.pos, self.b.tets, self.b.fixed, self.b.grabbed
        self.E, self.nu, self.unit = E_, nu, 1e-3
        self.length = surgical.BLOCK_MM[2]
        self.n_nodes = len(self.pos)

    def grab_disp(self, strain: float) -> np.ndarray:
        return np.tile([0.0, 0.0, strain * self.length], (len(self.grabbed), 1))


def add_arguments(p) -> None:
    p.add_argument(
        "--scene",
        choices=("tissue", "block"),
        default="tissue",
        help="tissue: the 30 x 30 x 20 mm block of 1.25 mm tetrahedra (10,625 nodes); block: the 1 m study block",
    )
    p.add_argument(
        "--element-mm", type=float, default=1.25, help="tissue: tetrahedron edge in mm (0.5..5; 1.25: 10,625 nodes)"
    )
    p.add_argument("--E", type=float, default=3e4, help="tissue: Young's modulus in Pa (1e3..1e6, default 30 kPa)")
    p.add_argument("--nu", type=float, default=0.45, help="tissue: Poisson's ratio (0..0.499)")
    p.add_argument("--n", type=int, default=22, help="block: nodes per edge (22: 10,648 nodes)")
    p.add_argument("--frames", type=int, default=400, help="most frames per phase (bounded)")
    p.add_argument(
        "--threads",
        type=int,
        nargs="?",
        const=numba.config.NUMBA_NUM_THREADS,
        default=1,
        metavar="N",
        help="each setting on one thread and on N numba threads (no N: all, the machine's cores), by the wall "
        "clock beside --busy processes; default 1: one thread only, its CPU time",
    )
    p.add_argument(
        "--busy",
        type=argtypes.count(0, MAX_BUSY),
        default=None,
        metavar="K",
        help=f"processes that keep a core busy each while the settings are timed (0..{MAX_BUSY}; "
        "default 2 with --threads, else 0)",
    )
    p.add_argument(
        "--only",
        default=None,
        help="semicolon-separated subset of the settings, each named by its start ('xpbd, 1;projective statics, CG')",
    )
    p.add_argument("--out", default="runs/bench-models", help="folder for results.json and results.md")
    p.add_argument(
        "--parts",
        default="settle",
        help="comma-separated: settle (the two pulls above), long (holds, drags and far pulls for seconds on the "
        "tissue block, tools/study/long_runs.py: long-runs.md and .json in --out), stiffness (the 3 mm lift held "
        "from rest at four stiffnesses up to nu 0.499, frames to 10/5/1 % of the model's own answer and of the FEM: "
        "stiffness.md and .json in --out); default settle",
    )


def reference(n: int, strains=(STRAIN,)):
    """The composite reference fields on block(n) at each of `strains` (a dict), and the scene."""
    coarse, fine = sc.block(7), sc.block(n)
    top = max(strains)
    fractions = tuple(s / top for s in strains)
    nl = solve_neohookean(
        coarse.pos, coarse.tets, E, NU, coarse.constrained, coarse.constrained_disp(top), fractions=fractions
    )
    lin_c = LinearFEM(coarse.pos, coarse.tets, E, NU, coarse.constrained)
    lin_f = LinearFEM(fine.pos, fine.tets, E, NU, fine.constrained)
    out = {}
    for s, f in zip(strains, fractions):
        corr = nl.u[f] - lin_c.solve(coarse.constrained_disp(s)).u
        out[s] = lin_f.solve(fine.constrained_disp(s)).u + coarse.interpolate(corr, fine.pos)
    return fine, out


def _phase(body, scene, ref, strain, frames, desc, solved=None, cpu=None):
    """Frames until within TARGET of ref after grabbing at `strain`; CPU seconds of each frame. `solved`,
    a list, gets the nodes each frame solved (the active region), where the body reports it; `cpu`, a
    list, the process's CPU seconds of each frame (every thread's)."""
    body.grab(scene.grabbed, scene.pos[scene.grabbed] + scene.grab_disp(strain))
    d = strain * scene.length
    times, reached, err = [], None, None
    for f in progress(range(1, frames + 1), desc=desc, unit="frame"):
        t0, c0 = _clock(), time.process_time()
        stats = body.step(1 / 60)
        times.append(_clock() - t0)
        if cpu is not None:
            cpu.append(time.process_time() - c0)
        if solved is not None:
            held = len(getattr(scene, "fixed", ())) + len(scene.grabbed)
            solved.append(int(stats.extra.get("solved", scene.n_nodes - held)))
        err = displacement_error(body.positions - scene.pos, ref, d)[0]
        if err <= TARGET:
            reached = f
            break
    return reached, err, times


_clock = time.thread_time


def _threads_text(n: int, busy: int) -> str:
    text = "one thread (CPU time)" if n == 1 else f"one thread, then {n} threads (wall clock)"
    beside = f", {busy} busy process{'es' if busy != 1 else ''} beside" if busy else ""
    return f"{text}{beside}, wait policy {wait_policy()}"


# a busy process spins, and looks up now and then whether its parent (its pid filled in) is still there:
# one killed outright never reaches the `finally` that ends its busy processes
_SPIN = "import os\nwhile os.getppid() == {}:\n    for _ in range(1_000_000): pass\n"


@contextlib.contextmanager
def busy_processes(k: int):
    """`k` processes that keep a core busy each for the body of the `with`, ended however it ends (an
    error, Ctrl-C): the busy machine that threads must not be slower on (the list of them, for tests)."""
    procs: list[subprocess.Popen] = []
    try:
        for _ in range(k):
            procs.append(
                subprocess.Popen(
                    [sys.executable, "-I", "-c", _SPIN.format(os.getpid())],
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                )
            )
        yield procs
    finally:
        for proc in procs:
            proc.kill()
        for proc in procs:
            proc.wait()


def _busy(args, threads: int) -> int:
    """--busy, or its default: two busy processes beside a run that compares thread counts."""
    busy = getattr(args, "busy", None)
    busy = (2 if threads > 1 else 0) if busy is None else busy
    if not (0 <= busy <= MAX_BUSY):
        raise UserError(f"--busy: expected 0..{MAX_BUSY} processes, got {busy}")
    return busy


def _rows(chosen: dict, scene, refs: dict, frames: int, threads: int) -> list[dict]:
    """Each setting's rows: on one thread and, with `threads` above 1, then on `threads`, one after the
    other so both meet the same load, the second with the moving tool on both (`_moving`)."""
    rows = []
    for name, make in chosen.items():
        for n in sorted({1, threads}):
            numba.set_num_threads(n)
            rows.append({**_measure(name, make, scene, refs, frames), "threads": n})
        if threads > 1:
            rows[-1]["moving_tool"] = _moving(make, scene, threads)
    numba.set_num_threads(threads)
    return rows


def _moving(make, scene, threads: int) -> dict:
    """Wall and CPU ms per frame (medians) of a tool that moves every frame, MOVING_FRAMES frames on one
    thread and as many on `threads`, the two taking turns every two frames so that both meet the same
    load; the first four frames (the held set's set-up among them) untimed."""
    body = make(scene)
    wall: dict[int, list[float]] = {1: [], threads: []}
    cpu: dict[int, list[float]] = {1: [], threads: []}
    for f in range(-4, 2 * MOVING_FRAMES):
        n = 1 if (f // 2) % 2 == 0 else threads
        numba.set_num_threads(n)
        body.grab(scene.grabbed, scene.pos[scene.grabbed] + scene.grab_disp(STRAIN + JIGGLE * (f % 2)))
        t0, c0 = time.perf_counter(), time.process_time()
        body.step(1 / 60)
        if f >= 0:
            wall[n].append(time.perf_counter() - t0)
            cpu[n].append(time.process_time() - c0)
    return {str(n): {"ms": 1e3 * float(np.median(wall[n])), "cpu_ms": 1e3 * float(np.median(cpu[n]))} for n in wall}


def run(args) -> int:
    if not (4 <= args.n <= 60):
        raise UserError(f"--n: expected 4..60 nodes per edge, got {args.n}")
    if not (1 <= args.frames <= 100_000):
        raise UserError(f"--frames: expected 1..100000, got {args.frames}")
    parts = parse_parts(getattr(args, "parts", None), ("settle", "long", "stiffness"), "settle")
    chosen = _chosen(args.only) if "settle" in parts else {}  # the long runs name their own settings
    threads = getattr(args, "threads", 1)
    if not (1 <= threads <= numba.config.NUMBA_NUM_THREADS):
        raise UserError(f"--threads: expected 1..{numba.config.NUMBA_NUM_THREADS} on this machine, got {threads}")
    busy = _busy(args, threads)
    numba.set_num_threads(threads)
    global _clock
    # one thread alone: its CPU time (steady under other load); one thread against several: the wall clock
    # for both, which counts every thread and the time spent waiting for a core
    _clock = time.thread_time if threads == 1 else time.perf_counter
    # settings under XPBD's substep rule are measured on purpose: their warning is the table's business
    warnings.filterwarnings("ignore", message="xpbd: .* substeps", category=UserWarning)
    if "long" in parts:
        print(bench_long_runs(args))
    if "stiffness" in parts:
        print(bench_stiffness(args))
    if "settle" not in parts:
        return 0
    scene, refs = _scene_and_references(args)
    with busy_processes(busy):
        rows = _rows(chosen, scene, refs, args.frames, threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    where = (
        f"the 30 x 30 x 20 mm tissue block of {scene.b.spacing:g} mm tetrahedra, E = {scene.E:g} Pa, "
        f"nu = {scene.nu:g}, lifted"
        if args.scene == "tissue"
        else "the 1 m block at 3 kPa, pulled"
    )
    info = {"load_average": os.getloadavg(), "nodes": scene.n_nodes, "budget_ms": BUDGET_MS, "scene": where}
    info["timing"] = _threads_text(threads, busy)
    info["threads"], info["busy_processes"], info["wait_policy"] = sorted({1, threads}), busy, wait_policy()
    info["rows"] = rows
    (out / "results.json").write_text(json.dumps(info, indent=1))
    md = _markdown(info, args.frames)
    (out / "results.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return 0


def _chosen(only: str | None) -> dict:
    """The settings --only names (each `;`-separated word starts a setting's name); all without it."""
    if not only:
        return SETTINGS
    want = [w.strip() for w in only.split(";") if w.strip()]
    chosen = {k: v for k, v in SETTINGS.items() if any(k.startswith(w) for w in want)}
    if not chosen:
        raise UserError(f"--only: no setting starts with {only!r}; settings: {'; '.join(SETTINGS)}")
    return chosen


def _scene_and_references(args):
    """The scene (--scene tissue: the surgical tissue block; else the study's 1 m block) and its
    reference displacements at the first pull and at the next one."""
    if args.scene == "tissue":
        if not (1e3 <= args.E <= 1e6) or not (0.0 <= args.nu <= 0.499):
            raise UserError(f"--E / --nu: expected 1e3..1e6 Pa and 0..0.499, got {args.E:g} and {args.nu:g}")
        element = getattr(args, "element_mm", 1.25)
        if not (0.5 <= element <= 5.0):
            raise UserError(f"--element-mm: expected 0.5..5 mm, got {element:g}")
        scene = TissueScene(element, args.E, args.nu)
        refs = {
            s: surgical.reference(scene.b, args.E, args.nu, s * scene.length, limit=10**6)
            for s in (STRAIN, STRAIN + STEP)
        }
    else:
        scene, refs = reference(args.n, (STRAIN, STRAIN + STEP))
        scene.E, scene.nu, scene.unit = E, NU, 1.0
    return scene, refs


def _measure(name: str, make, scene, refs: dict, frames: int) -> dict:
    """One setting's row: frame times, the first frame apart, and the frames to 5 % from rest and
    after the next pull."""
    warm = make(scene)
    warm.grab(scene.grabbed, scene.pos[scene.grabbed] + scene.grab_disp(STRAIN))
    warm.step(1 / 60)  # compilation and factorisation outside the timing
    body = make(scene)
    t0 = _clock()
    body.grab(scene.grabbed, scene.pos[scene.grabbed] + scene.grab_disp(STRAIN))
    body.step(1 / 60)  # the first frame after a new held set pays any factorisation: timed apart
    first_ms = 1e3 * (_clock() - t0)
    solved: list[int] = []
    cpu: list[float] = []
    cpu2: list[float] = []
    reached, err, times = _phase(body, scene, refs[STRAIN], STRAIN, frames, name, solved, cpu)
    reached = None if reached is None else reached + 1
    # from the converged state: the tool moves on by 5 % (a new target, the same held set)
    again, err2, times2 = (None, None, [])
    if reached is not None:
        again, err2, times2 = _phase(
            body, scene, refs[STRAIN + STEP], STRAIN + STEP, frames, name + " +5%", solved, cpu2
        )
    warm_ms = 1e3 * float(np.median(times2 or times))
    return {
        "setting": name,
        "nodes": scene.n_nodes,
        "ms_per_frame_median": warm_ms,
        "ms_per_frame_p90": 1e3 * float(np.percentile(times2 or times, 90)),
        "cpu_ms_per_frame_median": 1e3 * float(np.median(cpu2 or cpu)),
        "over_budget": warm_ms / BUDGET_MS,
        "first_frame_ms": first_ms,
        "frames_to_5_percent_from_rest": reached,
        "rms_error_from_rest": err,
        "frames_to_5_percent_after_next_pull": again,
        "rms_error_after_next_pull": err2,
        # the active region: the nodes a frame solves (all free nodes unless the body sleeps)
        "solved_nodes_median": int(np.median(solved)) if solved else None,
        "solved_nodes_max": max(solved) if solved else None,
    }


def _markdown(info: dict, frames: int) -> list[str]:
    md = [
        f"{info['nodes']} nodes, {info['scene']} 10 % from rest then 5 % more from the converged state, "
        f"{info['timing']}, load average {info['load_average'][0]:.1f}. ms/frame: median (and 90th percentile) "
        f"of the warm frames; / {BUDGET_MS:g} ms: the median over the frame budget.",
        "",
        "| setting | ms/frame | p90 | / 10 ms | first frame ms | frames to 5 % from rest | "
        "frames to 5 % after the next 5 % pull | RMS at end | nodes solved a frame (median, most) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in info["rows"]:
        a = r["frames_to_5_percent_from_rest"] or f"not within {frames}"
        b = r["frames_to_5_percent_after_next_pull"] or ("-" if r["rms_error_after_next_pull"] is None else "no")
        end = r["rms_error_after_next_pull"] if r["rms_error_after_next_pull"] is not None else r["rms_error_from_rest"]
        name = r["setting"] if r.get("threads", 1) == 1 else f"{r['setting']} ({r['threads']} threads)"
        md.append(
            f"| {name} | {r['ms_per_frame_median']:.1f} | {r['ms_per_frame_p90']:.1f} | "
            f"{r['over_budget']:.2f} | {r['first_frame_ms']:.0f} | {a} | {b} | {end:.3f} | "
            f"{r['solved_nodes_median']}, {r['solved_nodes_max']} |"
        )
    return md + _threads_md(info["rows"])


def _threads_md(rows: list[dict]) -> list[str]:
    """One thread against the most threads, setting by setting: the table's warm phase and the moving
    tool (nothing when one thread ran alone). Wall ms per frame, the process's CPU ms beside."""
    most = max((r.get("threads", 1) for r in rows), default=1)
    if most == 1:
        return []
    md = [
        "",
        f"{most} threads against one, wall ms per frame (CPU ms): the warm phase above, and {MOVING_FRAMES} "
        f"frames each of a tool moving every frame, the two thread counts taking turns every two frames.",
        "",
        f"| setting | warm phase, 1 thread | {most} threads | {most} / 1 | moving tool, 1 thread | "
        f"{most} threads | {most} / 1 |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for one, many in zip(rows[::2], rows[1::2]):
        a, b = many["moving_tool"]["1"], many["moving_tool"][str(most)]
        md.append(
            f"| {one['setting']} | {one['ms_per_frame_median']:.1f} ({one['cpu_ms_per_frame_median']:.1f}) | "
            f"{many['ms_per_frame_median']:.1f} ({many['cpu_ms_per_frame_median']:.1f}) | "
            f"{many['ms_per_frame_median'] / one['ms_per_frame_median']:.2f} | {a['ms']:.1f} ({a['cpu_ms']:.1f}) | "
            f"{b['ms']:.1f} ({b['cpu_ms']:.1f}) | {b['ms'] / a['ms']:.2f} |"
        )
    return md

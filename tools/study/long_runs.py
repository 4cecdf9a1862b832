"""Long runs on the surgical study's block: a tool that holds, drags and pulls tissue for seconds.

The study's table (tools/study/surgical.py) stops after half a second of holding a 3 mm lift; a tool in
the simulator holds tissue for seconds, drags it slowly and pulls it far. This module owns the
scenarios for that, run through the body API at 60 Hz on the same 30 x 30 x 20 mm block (base fixed,
the 6 x 6 mm top patch or a 6 x 6 mm top corner held), each a sequence of per-frame targets:

- hold: the patch lifted 3 mm at once and held 10 s;
- drag: the patch moved 4 mm sideways over 1.5 s, its target moving every frame;
- drag-hold: that drag, then 5 s held; corner drag-hold: the same at a top corner of the block;
- shear and lift, the far pulls: the patch moved 12 mm sideways, or lifted half the block's height
  (10 mm), at once, and held 2 s.

Thesis 6.2.2 measures ChainMail's frame rates from a small to a large displacement of a picked element
and times a worst case in which an element is moved at a constant rate around a square path many
times over; its figures are speed only. Here each run keeps, beside its cost, what a long hold or a
far pull does to the shape:

- error at the end: RMS nodal distance to the converged neo-Hookean P1 FEM of the same mesh and the
  final target (tools/study/fem_nonlinear.py), over the pull (the final target's displacement);
- flicker: the largest frame-to-frame move of any node while held, after the hold's first second,
  over the pull (a body at rest reads 0; one alternating between two shapes reads their distance);
- min J: the smallest determinant of the deformation gradient of any tetrahedron over the whole run,
  computed here from the rest and current positions, not by the body (below 0: an inverted element);
- overshoot: the largest displacement of any node over the run, over the pull, minus 1 (0 when no node
  ever moves farther than the tool; the FEM's own figure is kept beside it);
- median CPU ms (time.process_time, one numba thread unless the caller chose otherwise) and wall ms of
  a frame, the first frame left out (it pays any factorisation).

A model that takes a `sleep` setting (the hybrid body) runs every scenario twice: without sleeping and
with far nodes sleeping (SLEEP). The FEM solutions are kept in a cache folder when one is given (the
command lines use CACHE, in the system's temporary folder, so that none lands beside a report), so a later
run on the same mesh, material and targets reads them instead of solving again (minutes at 10k nodes).

The stiffness part (`chainsim study surgical --parts stiffness`) holds the 3 mm patch lift from rest for
5 s at four materials, soft to nearly incompressible (STIFF_MATERIALS), and counts the frames each setting
takes to come within 10, 5 and 1 % of its own converged answer (the same body with CONVERGED_ITERATIONS
iterations a frame; |u - u*| / |u*| over the displacement field) and of the FEM (RMS over the lift). Its
own answer says how fast the solver settles; the FEM says where it settles, and the two differ by what
the model's energy gets wrong.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import platform
import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numba
import numpy as np

from chainsim.systems.engine import model_params
from chainsim.systems.engine.bodies.factory import make_body
from chainsim.systems.engine.errors import UserError

from . import surgical
from .fem_linear import LockingWarning
from .fem_nonlinear import solve_neohookean

logger = logging.getLogger(__name__)

FPS = 60
DEFAULT_MM = 1.25  # the study's 10,625-node mesh
QUICK_MM = 2.5  # 1,521 nodes: seconds per scenario, for tests and --quick
SLEEP = 0.015  # the sleeping variant's threshold (a share of the displacement scale)
CORNER_MM = surgical.PATCH_MM  # the corner region: this square at a top corner of the block
MAX_RUN_S = 300.0  # a run whose warm frames would take longer than this (CPU) is stopped early
MOVED = 0.01  # a node counts as moved when its displacement exceeds this share of the pull
CACHE = Path(tempfile.gettempdir()) / "chainsim-long-runs-fem"  # the command lines' FEM cache
FEM_VERSION = 1  # part of the cache key: a change to how the references are solved invalidates the cache

#: the settings run: (model, name, params); models that take `sleep` also run with SLEEP
SETTINGS: list[tuple[str, str, dict[str, Any]]] = [
    ("hybrid", "hybrid (defaults)", {}),
    ("projective", "projective (defaults: dynamic, 10 it)", {}),
    (
        "projective",
        "projective statics, CG 6, 1 it",
        {"dynamic": False, "solver": "cg", "cg_iterations": 6, "iterations": 1, "rotation_iterations": 1},
    ),
    ("xpbd", "XPBD (defaults: substeps by rule)", {}),
    ("xpbd", "XPBD, 4 substeps", {"substeps": 4}),
]


@dataclass(frozen=True)
class Scenario:
    """Per-frame targets: the held region moves by `offset` (mm) linearly over the first `ramp` frames
    (1: at once) and stays there up to frame `frames`; flicker is read from `settle` frames into the hold."""

    name: str
    what: str
    offset: tuple[float, float, float]
    ramp: int
    frames: int
    region: str = "patch"
    settle: int = FPS

    @property
    def pull(self) -> float:
        return float(np.linalg.norm(self.offset))

    def fraction(self, frame: int) -> float:
        """The share of the offset the target has reached on `frame` (1-based)."""
        return min(frame / self.ramp, 1.0)

    def counts_flicker(self, frame: int) -> bool:
        """Whether the change into `frame` is a held frame's, past the hold's first `settle` frames."""
        return frame >= self.ramp + self.settle


SCENARIOS = [
    Scenario("hold", "the patch lifted 3 mm at once, held 10 s", (0.0, 0.0, surgical.LIFT_MM), 1, 10 * FPS),
    Scenario("drag", "the patch moved 4 mm sideways over 1.5 s", (4.0, 0.0, 0.0), 90, 90),
    Scenario("drag-hold", "the patch moved 4 mm sideways over 1.5 s, held 5 s", (4.0, 0.0, 0.0), 90, 90 + 5 * FPS),
    Scenario(
        "corner-drag-hold",
        "a top corner moved 4 mm sideways over 1.5 s, held 5 s",
        (4.0, 0.0, 0.0),
        90,
        90 + 5 * FPS,
        region="corner",
    ),
    Scenario("shear", "the patch moved 12 mm sideways at once, held 2 s", (12.0, 0.0, 0.0), 1, 2 * FPS),
    Scenario(
        "lift",
        "the patch lifted 10 mm (half the block) at once, held 2 s",
        (0.0, 0.0, surgical.BLOCK_MM[2] / 2),
        1,
        2 * FPS,
    ),
]


def scenarios(time_scale: float = 1.0, names: list[str] | None = None) -> list[Scenario]:
    """The scenarios (those named, in their order), their frame counts scaled by `time_scale` (tests run them
    shortened; the figures come from time_scale 1)."""
    known = {s.name: s for s in SCENARIOS}
    bad = [n for n in names or [] if n not in known]
    if bad:
        raise UserError(f"scenarios: unknown {', '.join(bad)}; expected some of {', '.join(known)}")
    chosen = [known[n] for n in names] if names else SCENARIOS
    if time_scale == 1.0:
        return list(chosen)

    def scaled(n: int) -> int:
        return max(1, round(n * time_scale))

    return [replace(s, ramp=scaled(s.ramp), frames=scaled(s.frames), settle=scaled(s.settle)) for s in chosen]


def region(b: surgical.Block, name: str) -> np.ndarray:
    """The held nodes: the study's top patch, or a CORNER_MM square at the top corner nearest the origin."""
    if name == "patch":
        return b.grabbed
    top = b.pos[:, 2] > b.pos[:, 2].max() - 1e-9
    return np.flatnonzero(top & (b.pos[:, 0] <= CORNER_MM + 1e-9) & (b.pos[:, 1] <= CORNER_MM + 1e-9))


# -- the metrics ---------------------------------------------------------------------------------------
def _edge_matrices(p: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T, 3, 3): each tetrahedron's edges from its first corner, as columns."""
    q = p[tets]
    return np.stack([q[:, 1] - q[:, 0], q[:, 2] - q[:, 0], q[:, 3] - q[:, 0]], axis=2)


def jacobians(rest: np.ndarray, tets: np.ndarray, x: np.ndarray) -> np.ndarray:
    """det F of each tetrahedron: F = D(x) D(rest)^-1 with D the edge matrix, so det F = det D(x) / det D(rest)."""
    return np.linalg.det(_edge_matrices(x, tets)) / np.linalg.det(_edge_matrices(rest, tets))


class Tracker:
    """The shape figures of a run, kept frame by frame without storing the frames: min J, the largest
    displacement, and the largest frame-to-frame (and two-frame) node move over the frames that count."""

    def __init__(self, rest: np.ndarray, tets: np.ndarray, pull: float):
        self.rest, self.tets, self.pull = rest, tets, pull
        self._rest_det = np.linalg.det(_edge_matrices(rest, tets))
        self.min_J = math.inf
        self.peak = 0.0
        self.flicker: float | None = None
        self.flicker_two: float | None = None
        self._last: list[np.ndarray] = []

    def frame(self, x: np.ndarray, held: bool) -> None:
        """Take the shape `x` of a frame; `held`: the change into it counts as flicker."""
        self.min_J = min(self.min_J, float(np.min(np.linalg.det(_edge_matrices(x, self.tets)) / self._rest_det)))
        self.peak = max(self.peak, float(np.max(np.linalg.norm(x - self.rest, axis=1))))
        if held and self._last:
            step = float(np.max(np.linalg.norm(x - self._last[-1], axis=1))) / self.pull
            self.flicker = max(self.flicker or 0.0, step)
            if len(self._last) == 2:
                # a body that alternates between two shapes barely changes over two frames: this beside the
                # flicker says whether the frame-to-frame change is an alternation or a slow drift
                two = float(np.max(np.linalg.norm(x - self._last[0], axis=1))) / self.pull
                self.flicker_two = max(self.flicker_two or 0.0, two)
        self._last = [*self._last[-1:], x.copy()]

    def figures(self) -> dict:
        return {
            "min_J": self.min_J,
            "overshoot": self.peak / self.pull - 1.0,
            "flicker": self.flicker,
            "flicker_two_frames": self.flicker_two,
        }


# -- the reference -------------------------------------------------------------------------------------
def reference(
    b: surgical.Block, held: np.ndarray, offset, E: float, nu: float, cache: Path | None = None
) -> tuple[np.ndarray | None, dict]:
    """The converged neo-Hookean P1 displacement (mm) with `held` moved by `offset` and the base fixed, and
    how it was had; None where the load path did not converge."""
    key = json.dumps([FEM_VERSION, b.spacing, len(b.pos), E, nu, held.tolist(), list(map(float, offset))])
    path = cache / f"fem-{hashlib.sha1(key.encode()).hexdigest()[:16]}.npz" if cache is not None else None
    if path is not None and path.exists():
        return np.load(path)["u"], {"status": "read from the cache", "seconds": 0.0}
    c = np.unique(np.concatenate([b.fixed, held]))
    disp = np.zeros((len(c), 3))
    disp[np.isin(c, held)] = offset
    t0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LockingWarning)
        res = solve_neohookean(b.pos * 1e-3, b.tets, E, nu, c, disp * 1e-3, max_halvings=12)
    info = {"status": res.status, "seconds": time.process_time() - t0, "load_steps": res.load_steps}
    if 1.0 not in res.u:
        logger.warning(f"long runs: the neo-Hookean reference did not converge ({res.status})")
        return None, info
    u = res.u[1.0] * 1e3
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(path, u=u)
        except OSError as e:  # the cache only saves time: a run goes on without it
            logger.warning(f"long runs: cannot keep the reference in {path.parent} ({e.strerror or e})")
    return u, info


# -- one run -------------------------------------------------------------------------------------------
def variants(only: list[str] | None = None) -> list[tuple[str, str, dict]]:
    """Each setting, and with SLEEP beside it where its model takes a `sleep` setting; with `only`, those whose
    name starts with one of its words, or UserError."""
    out = []
    for model, name, params in SETTINGS:
        out.append((model, name, dict(params)))
        if "sleep" in model_params.params(model) and not params.get("sleep"):
            out.append((model, f"{name}, sleeping {SLEEP:g}", {**params, "sleep": SLEEP}))
    if only:
        out = [v for v in out if any(v[1].startswith(w) for w in only)]
        if not out:
            names = "; ".join(v[1] for v in variants())
            raise UserError(f"--only: no long-run setting starts with {'; '.join(only)!r}; settings: {names}")
    return out


def run_one(
    b: surgical.Block, sc: Scenario, model: str, params: dict, E: float, nu: float, max_seconds: float = MAX_RUN_S
) -> tuple[np.ndarray | None, dict]:
    """Drive a new body through the scenario's targets; its final positions and the run's figures."""
    kw = dict(params) if model == "chainmail" else {**params, "E": E, "nu": nu, "unit": 1e-3}
    with warnings.catch_warnings():
        # settings under a model's own rules (XPBD's substeps) are measured on purpose: the table says so
        warnings.simplefilter("ignore", UserWarning)
        body = make_body(model, b.pos, tets=b.tets, fixed=b.fixed, **kw)
        return _drive(body, b, sc, max_seconds)


def _drive(body, b: surgical.Block, sc: Scenario, max_seconds: float) -> tuple[np.ndarray | None, dict]:
    held = region(b, sc.region)
    track = Tracker(b.pos, b.tets, sc.pull)
    start, offset = b.pos[held], np.asarray(sc.offset)
    cpu: list[float] = []
    wall: list[float] = []
    solved = None
    for f in range(1, sc.frames + 1):
        c0, w0 = time.process_time(), time.perf_counter()
        if f == 1 or sc.fraction(f) != sc.fraction(f - 1):
            body.grab(held, start + sc.fraction(f) * offset)
        stats = body.step(1.0 / FPS)
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
        solved = stats.extra.get("solved", solved)
        track.frame(body.positions, sc.counts_flicker(f))
        if f == 3 and np.mean(cpu[1:]) * sc.frames > max_seconds:
            ms = 1e3 * float(np.mean(cpu[1:]))
            why = f"stopped after 3 frames: {ms:.0f} ms a frame, {sc.frames} would take {ms * sc.frames / 1e3:.0f} s"
            return None, {"status": why, "cpu_ms": ms, "wall_ms": 1e3 * float(np.mean(wall[1:])), "frames_run": f}
    warm_cpu, warm_wall = cpu[1:] or cpu, wall[1:] or wall
    info = {
        "status": "ran",
        "frames_run": sc.frames,
        "cpu_ms": 1e3 * float(np.median(warm_cpu)),
        "wall_ms": 1e3 * float(np.median(warm_wall)),
        "first_frame_ms": 1e3 * wall[0],
        "max_wall_ms": 1e3 * max(warm_wall),
        **track.figures(),
    }
    if solved is not None:
        info["solved_nodes_last_frame"] = int(solved)
    if body.model == "xpbd":
        info["substeps"] = int(getattr(body, "substeps", 0))
    return body.positions - b.pos, info


def _moved(u: np.ndarray, pull: float) -> int:
    return int(np.count_nonzero(np.linalg.norm(u, axis=1) > MOVED * pull))


# -- the whole set -------------------------------------------------------------------------------------
def run(
    element_mm: float = DEFAULT_MM,
    E: float = 3e4,
    nu: float = 0.45,
    *,
    names: list[str] | None = None,
    only: list[str] | None = None,
    time_scale: float = 1.0,
    cache: Path | None = None,
    threads: int | None = 1,
    max_seconds: float = MAX_RUN_S,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """Every scenario (or those `names` gives) for every setting (SETTINGS with their sleeping variants, or
    those whose name starts with a word of `only`) on the block of `element_mm` tetrahedra; `threads`: numba
    threads for the runs (None: as they are)."""
    b = surgical.block(element_mm)
    chosen = scenarios(time_scale, names)
    settings = variants(only)
    before = numba.get_num_threads()
    if threads is not None:
        numba.set_num_threads(threads)
    try:
        refs = {}
        ref_info = []
        for sc in chosen:
            key = (sc.region, sc.offset)
            if key not in refs:
                if progress:
                    progress(f"long runs: neo-Hookean reference for {sc.name} on {len(b.pos)} nodes")
                refs[key], info = reference(b, region(b, sc.region), sc.offset, E, nu, cache)
                ref_info.append({"scenario": sc.name, **info})
        rows = []
        for sc in chosen:
            ref = refs[(sc.region, sc.offset)]
            for model, name, params in settings:
                if progress:
                    progress(f"long runs: {sc.name}, {name} ({sc.frames} frames)")
                rows.append(_row(b, sc, model, name, params, E, nu, ref, max_seconds))
    finally:
        numba.set_num_threads(before)
    return {
        "element_mm": element_mm,
        "nodes": len(b.pos),
        "tets": len(b.tets),
        "E": E,
        "nu": nu,
        "fps": FPS,
        "threads": threads if threads is not None else before,
        "scenarios": [{**asdict(sc), "pull_mm": sc.pull, "held_nodes": len(region(b, sc.region))} for sc in chosen],
        "fem": _fem_figures(b, chosen, refs),
        "references": ref_info,
        "fem_cache": str(cache) if cache is not None else None,
        "rows": rows,
    }


def _row(b, sc, model, name, params, E, nu, ref, max_seconds) -> dict:
    try:
        u, info = run_one(b, sc, model, params, E, nu, max_seconds)
    except UserError as e:  # a setting the model refuses on this mesh, or a step that diverged
        u, info = None, {"status": f"refused: {e}"}
    row = {"scenario": sc.name, "model": model, "setting": name, "params": params, **info}
    if u is not None:
        row["nodes_moved"] = _moved(u, sc.pull)
        if ref is not None:
            row["error_end"] = float(np.sqrt(np.mean(np.sum((u - ref) ** 2, axis=1)))) / sc.pull
    return row


def _fem_figures(b: surgical.Block, chosen: list[Scenario], refs: dict) -> dict:
    """Per scenario, the reference's own min J, overshoot and moved nodes (None where it did not converge)."""
    out: dict[str, dict[str, float] | None] = {}
    for sc in chosen:
        u = refs[(sc.region, sc.offset)]
        if u is None:
            out[sc.name] = None
            continue
        out[sc.name] = {
            "min_J": float(jacobians(b.pos, b.tets, b.pos + u).min()),
            "overshoot": float(np.max(np.linalg.norm(u, axis=1))) / sc.pull - 1.0,
            "nodes_moved": _moved(u, sc.pull),
        }
    return out


# -- writing -------------------------------------------------------------------------------------------
def _f(v, fmt: str = "{:.3f}") -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return f"{v:.2e}" if abs(v) >= 1e4 else fmt.format(v)  # a blown-up run stays one short cell


def markdown(results: dict, command: str, machine: str) -> str:
    """The runs as tables, one per scenario, the FEM's own figures above each."""
    L = [
        "# Long runs: holding, dragging and pulling for seconds",
        "",
        f"The {surgical.BLOCK_MM[0]:g} x {surgical.BLOCK_MM[1]:g} x {surgical.BLOCK_MM[2]:g} mm block of "
        f"{results['element_mm']:g} mm tetrahedra ({results['nodes']} nodes), E = {results['E']:g} Pa, "
        f"nu = {results['nu']:g}, base fixed, at {results['fps']} Hz. Error: RMS nodal distance to the converged "
        "neo-Hookean FEM of the final target at the last frame, over the pull; flicker: the largest frame-to-frame "
        "move of a node after the hold's first second, over the pull (2-frame: the same over two frames, near 0 "
        "where the body alternates between two shapes); min J: the smallest tetrahedron's det F "
        "over the run; overshoot: the largest node displacement over the run over the pull, minus 1; ms: "
        f"median CPU (one process, {results['threads']} numba thread(s)) and wall per frame after the first.",
        "",
        f"Made with `{command}` on {machine}.",
        "",
    ]
    for sc in results["scenarios"]:
        fem = results["fem"].get(sc["name"])
        L += [f"## {sc['name']}: {sc['what']} ({sc['frames']} frames, {sc['held_nodes']} held nodes)", ""]
        if fem is None:
            L += ["The FEM reference did not converge: no error at the end.", ""]
        else:
            L += [
                f"FEM: min J {fem['min_J']:.2f}, overshoot {fem['overshoot']:+.3f}, "
                f"{fem['nodes_moved']} nodes moved more than {MOVED:.0%} of the pull.",
                "",
            ]
        L += [
            "| setting | error at end | flicker | 2-frame | min J | overshoot | nodes moved | CPU ms | wall ms "
            "| status |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
        ]
        for r in (r for r in results["rows"] if r["scenario"] == sc["name"]):
            L.append(
                f"| {r['setting']} | {_f(r.get('error_end'))} | {_f(r.get('flicker'), '{:.4f}')} | "
                f"{_f(r.get('flicker_two_frames'), '{:.4f}')} | "
                f"{_f(r.get('min_J'), '{:.2f}')} | {_f(r.get('overshoot'), '{:+.3f}')} | {r.get('nodes_moved', '-')} | "
                f"{_f(r.get('cpu_ms'), '{:.1f}')} | {_f(r.get('wall_ms'), '{:.1f}')} | {r['status']} |"
            )
        L.append("")
    return "\n".join(L) + "\n"


def _write(results: dict, out_dir, stem: str, text: str, what: str) -> Path:
    """STEM.json and STEM.md (holding `text`) in `out_dir`; the markdown's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    try:
        (out / f"{stem}.json").write_text(json.dumps(results, indent=1, default=str), encoding="utf-8")
        md = out / f"{stem}.md"
        md.write_text(text, encoding="utf-8")
    except OSError as e:
        raise UserError(f"{out}: cannot write the {what}' results ({e.strerror or e})") from None
    return md


def write(results: dict, out_dir, command: str, machine: str) -> Path:
    """long-runs.json and long-runs.md in `out_dir`; the markdown's path."""
    return _write(results, out_dir, "long-runs", markdown(results, command, machine), "long runs")


# -- the command lines' parts ----------------------------------------------------------------------------
def parts(text: str | None, known: tuple[str, ...], default: str, flag: str = "--parts") -> list[str]:
    """The comma-separated parts a command line names, each one of `known`, or UserError."""
    want = [w.strip() for w in (text or default).split(",") if w.strip()]
    bad = [w for w in want if w not in known]
    if bad or not want:
        raise UserError(f"{flag}: expected a comma-separated list of {', '.join(known)}, got {text!r}")
    return want


def machine() -> str:
    """The machine a figure came from, in a few words."""
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, load {load:.1f}"


def bench(args) -> str:
    """`chainsim bench models --parts long`: the scenarios on the tissue block the bench's --element-mm,
    --E and --nu describe, the settings --only names; writes long-runs.json/.md in --out, returns the text."""
    if getattr(args, "scene", "tissue") != "tissue":
        raise UserError("--parts long: runs on the tissue block (--scene tissue)")
    E, nu, element = getattr(args, "E", 3e4), getattr(args, "nu", 0.45), getattr(args, "element_mm", DEFAULT_MM)
    if not (1e3 <= E <= 1e6) or not (0.0 <= nu <= 0.499):
        raise UserError(f"--E / --nu: expected 1e3..1e6 Pa and 0..0.499, got {E:g} and {nu:g}")
    if not (0.5 <= element <= 5.0):
        raise UserError(f"--element-mm: expected 0.5..5 mm, got {element:g}")
    only = [w.strip() for w in (getattr(args, "only", None) or "").split(";") if w.strip()]
    variants(only)  # a bad --only is one line before any reference is solved
    out = Path(args.out)
    results = run(element, E, nu, only=only, cache=CACHE, threads=None, progress=logger.info)
    command = f"chainsim bench models --parts long --element-mm {element:g} --E {E:g} --nu {nu:g}"
    command += f" --only {';'.join(only)!r}" if only else ""
    command += f" --threads {args.threads}" if getattr(args, "threads", 1) != 1 else ""
    md = write(results, out, command, machine())
    return md.read_text(encoding="utf-8")


# -- stiffness: how many frames a held lift takes to settle, soft to nearly incompressible -----------------
#: the materials (E in Pa, nu): soft to stiff at nu 0.45, then towards incompressible, where a solver whose
#: iteration ignores the coupling of the axes through the volume term slows down most
STIFF_MATERIALS = [(1e3, 0.45), (3e4, 0.45), (1e5, 0.49), (3e4, 0.499)]
STIFF_FRAMES = 300  # 5 s held
STIFF_LEVELS = (0.10, 0.05, 0.01)
CONVERGED_ITERATIONS = 40  # the model's own answer: the same body with this many iterations a frame
#: the FEM's displacement under displacement loads alone does not depend on E (the stress scales with it),
#: so one solve per nu, at this E, serves every stiffness (and shares the hold's cached reference)
FEM_E = 3e4
STIFF_SETTINGS = [
    ("hybrid", "hybrid (defaults)", {}),
    (
        "projective",
        "projective statics, CG 6, 1 it",
        {"dynamic": False, "solver": "cg", "cg_iterations": 6, "iterations": 1, "rotation_iterations": 1},
    ),
]


def frames_to(errors, levels=STIFF_LEVELS) -> list[int | None]:
    """Per level, the first frame (1-based) from which every later error stays at or below it; None where the
    last frame's is above. A run that dips below a level and comes back above counts from its last arrival,
    so a frame count says the body has stayed there, not that it passed by."""
    e = np.asarray(errors, dtype=float)
    out: list[int | None] = []
    for level in levels:
        within = e <= level  # NaN counts as outside
        if not len(e) or not within[-1]:
            out.append(None)
            continue
        outside = np.flatnonzero(~within)
        out.append(int(outside[-1]) + 2 if len(outside) else 1)
    return out


def _lift(body, b: surgical.Block, frames: int, each: Callable[[np.ndarray], None]) -> list[float]:
    """Lift the patch 3 mm at once from rest and hold it `frames` frames, `each` given every frame's
    displacement (not kept: 300 frames of a 10k-node field are 80 MB); each warm frame's CPU ms."""
    held = b.grabbed
    body.grab(held, b.pos[held] + np.array([0.0, 0.0, surgical.LIFT_MM]))
    cpu = []
    for _ in range(frames):
        c0 = time.process_time()
        body.step(1.0 / FPS)
        cpu.append(1e3 * (time.process_time() - c0))
        each(body.positions - b.pos)
    return cpu[1:] or cpu


def _stiff_body(model: str, params: dict, b: surgical.Block, E: float, nu: float):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        return make_body(model, b.pos, tets=b.tets, fixed=b.fixed, **{**params, "E": E, "nu": nu, "unit": 1e-3})


def stiffness_row(
    b: surgical.Block, model: str, name: str, params: dict, E: float, nu: float, ref: np.ndarray | None, frames: int
) -> dict:
    """One setting at one material: its own converged answer (CONVERGED_ITERATIONS a frame), then the
    setting's run, with the frames to each of STIFF_LEVELS of both that answer and the FEM `ref`."""
    row: dict = {"setting": name, "model": model, "params": params, "E": E, "nu": nu, "frames": frames}
    last: list[np.ndarray] = []  # the converged run's last two frames

    def keep(u: np.ndarray) -> None:
        last[:] = [*last[-1:], u]

    try:
        _lift(_stiff_body(model, {**params, "iterations": CONVERGED_ITERATIONS}, b, E, nu), b, frames, keep)
        star = last[-1]
        scale = float(np.linalg.norm(star))
        own_err: list[float] = []
        fem_err: list[float] = []

        def each(u: np.ndarray) -> None:
            own_err.append(float(np.linalg.norm(u - star)) / scale if scale else math.nan)
            if ref is not None:
                fem_err.append(float(np.sqrt(np.mean(np.sum((u - ref) ** 2, axis=1)))) / surgical.LIFT_MM)

        cpu = _lift(_stiff_body(model, params, b, E, nu), b, frames, each)
    except UserError as e:  # a setting the model refuses, or a step that diverged
        return {**row, "status": f"refused: {e}"}
    # how still the converged run was at its end: its last frame's change relative to its answer
    row["own_last_change"] = float(np.linalg.norm(last[-1] - last[0])) / scale if len(last) == 2 and scale else None
    row.update(
        status="ran",
        cpu_ms=float(np.median(cpu)),
        cpu_ms_mean=float(np.mean(cpu)),
        own_frames=frames_to(own_err),
        own_end=own_err[-1],
    )
    row["own_fem_error"] = None
    if ref is not None:
        row.update(fem_frames=frames_to(fem_err), fem_end=fem_err[-1])
        row["own_fem_error"] = float(np.sqrt(np.mean(np.sum((star - ref) ** 2, axis=1)))) / surgical.LIFT_MM
    return row


def stiffness(
    element_mm: float = DEFAULT_MM,
    *,
    materials: list[tuple[float, float]] | None = None,
    frames: int | None = None,
    only: list[str] | None = None,
    cache: Path | None = None,
    threads: int | None = 1,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """The 3 mm patch lift held from rest for `frames` frames at each of `materials` (STIFF_MATERIALS), for
    each of STIFF_SETTINGS (those whose name starts with a word of `only`); `frames`: STIFF_FRAMES unless told."""
    b = surgical.block(element_mm)
    frames = frames or STIFF_FRAMES
    settings = [s for s in STIFF_SETTINGS if not only or any(s[1].startswith(w) for w in only)]
    if not settings:
        raise UserError(f"stiffness: no setting starts with {'; '.join(only or [])!r}")
    before = numba.get_num_threads()
    if threads is not None:
        numba.set_num_threads(threads)
    rows, refs = [], []
    try:
        for E, nu in materials or STIFF_MATERIALS:
            if progress:
                progress(f"stiffness: neo-Hookean reference at nu {nu:g} on {len(b.pos)} nodes")
            ref, info = reference(b, b.grabbed, (0.0, 0.0, surgical.LIFT_MM), FEM_E, nu, cache)
            refs.append({"E": E, "nu": nu, **info})
            for model, name, params in settings:
                if progress:
                    progress(f"stiffness: {name} at {E:g} Pa, nu {nu:g} ({frames} frames, and its own answer)")
                rows.append(stiffness_row(b, model, name, params, E, nu, ref, frames))
    finally:
        numba.set_num_threads(before)
    return {
        "element_mm": element_mm,
        "nodes": len(b.pos),
        "fps": FPS,
        "frames": frames,
        "levels": list(STIFF_LEVELS),
        "converged_iterations": CONVERGED_ITERATIONS,
        "threads": threads if threads is not None else before,
        "references": refs,
        "fem_cache": str(cache) if cache is not None else None,
        "rows": rows,
    }


def stiffness_markdown(results: dict, command: str, machine: str) -> str:
    """The stiffness runs as one table: frames to each level of the model's own answer and of the FEM."""
    lv = "/".join(f"{x:.0%}" for x in results["levels"])

    def counts(v) -> str:
        return " / ".join("-" if n is None else str(n) for n in v) if v is not None else "-"

    L = [
        "# Stiffness: a held lift settling, soft to nearly incompressible",
        "",
        f"The 3 mm patch lift of the {surgical.BLOCK_MM[0]:g} x {surgical.BLOCK_MM[1]:g} x {surgical.BLOCK_MM[2]:g} "
        f"mm block of {results['element_mm']:g} mm tetrahedra ({results['nodes']} nodes), at once from rest and "
        f"held {results['frames']} frames at {results['fps']} Hz. Frames to {lv}: the first frame from which the "
        "error stays within that share to the end (-: not by the end). Own answer: the same body with "
        f"{results['converged_iterations']} iterations a frame after {results['frames']} frames; its error is "
        "|u - u*| / |u*| over the whole displacement field. FEM: RMS nodal distance to the converged "
        "neo-Hookean P1 FEM over the lift. ms: median and mean CPU per frame after the first "
        f"({results['threads']} numba thread(s)); a body at rest stops iterating, so its median is the cost of a "
        "still frame and its mean counts the frames it took to get there.",
        "",
        f"Made with `{command}` on {machine}.",
        "",
        f"| setting | E (kPa) | nu | frames to {lv} of own answer | own at end | frames to {lv} of FEM "
        "| FEM at end | own answer vs FEM | CPU ms (median, mean) | status |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in results["rows"]:
        L.append(
            f"| {r['setting']} | {r['E'] / 1e3:g} | {r['nu']:g} | {counts(r.get('own_frames'))} | "
            f"{_f(r.get('own_end'), '{:.4f}')} | {counts(r.get('fem_frames'))} | {_f(r.get('fem_end'), '{:.4f}')} | "
            f"{_f(r.get('own_fem_error'), '{:.4f}')} | {_f(r.get('cpu_ms'), '{:.1f}')}, "
            f"{_f(r.get('cpu_ms_mean'), '{:.1f}')} | {r['status']} |"
        )
    return "\n".join(L) + "\n"


def write_stiffness(results: dict, out_dir, command: str, machine: str) -> Path:
    """stiffness.json and stiffness.md in `out_dir`; the markdown's path."""
    return _write(results, out_dir, "stiffness", stiffness_markdown(results, command, machine), "stiffness runs")


def bench_stiffness(args) -> str:
    """`chainsim bench models --parts stiffness`: the held lift at each of STIFF_MATERIALS (not --E / --nu: the
    part is the sweep) on the tissue block of --element-mm, the settings --only names; writes stiffness.json/.md
    in --out, returns the text."""
    if getattr(args, "scene", "tissue") != "tissue":
        raise UserError("--parts stiffness: runs on the tissue block (--scene tissue)")
    element = getattr(args, "element_mm", DEFAULT_MM)
    if not (0.5 <= element <= 5.0):
        raise UserError(f"--element-mm: expected 0.5..5 mm, got {element:g}")
    only = [w.strip() for w in (getattr(args, "only", None) or "").split(";") if w.strip()]
    results = stiffness(element, only=only, cache=CACHE, threads=None, progress=logger.info)
    command = f"chainsim bench models --parts stiffness --element-mm {element:g}"
    command += f" --only {';'.join(only)!r}" if only else ""
    command += f" --threads {args.threads}" if getattr(args, "threads", 1) != 1 else ""
    return write_stiffness(results, Path(args.out), command, machine()).read_text(encoding="utf-8")

"""`chainsim bench sheet`: the surface models (SurfaceChainMail, XPBD and projective dynamics on triangles)
against a sheet reference none of them is built from, as the cutting trainer's layers are run.

The scene: a 40 x 40 mm tissue layer 2 mm thick (E from --E, nu from --nu), clamped along its four edges, a
central 4 x 4 mm patch held through its thickness (a grasping tool) and lifted by each of --lifts (default 2, 4 and
6 mm) from rest. The reference: the study's neo-Hookean P1 FEM (tools/study/fem_nonlinear.py) on a thin
tetrahedral slab of the sheet (`--element-mm` in-plane, `--layers` elements through the thickness), its
clamped edges and lifted patch prescribed through the thickness; its discretisation error is measured
once against the same slab coarsened (twice the in-plane spacing, half the layers, at least two) and
stated with the figures. The surface models run on the triangle mesh of the slab's mid-plane nodes (the
same in-plane nodes: no interpolation), their edges fixed and their patch grabbed; a row's error is RMS
over every mid-surface node of |u - u_ref| / lift (clamped nodes included, as in the surgical study), and
its worst node. Two shapes no physics makes (only the patch moves; a straight-sided cone from the patch
down to the clamped edge) give the floor a model must beat for its error to mean anything.

Cost as `chainsim bench models` measures it: one thread, CPU time (thread_time) per 60 Hz frame. A body
runs --frames frames holding the lift (the error at the end; the frames to settle: the first frame from
which it stays within 1 % of the lift of its final shape; the frames to come within 5 % of the
reference), then 20 frames with the tool moving +-0.05 mm each frame: their median is the ms per frame
(a ChainMail body does its work only when its target moves, so the held frames would show it free); the
same with one grabbed element, as the cutting trainer's grasping tool holds.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt
import numba
import numpy as np
from scipy.interpolate import RegularGridInterpolator
from scipy.spatial import cKDTree

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.bodies.factory import make_body
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.progress import progress
from chainsim.tools.study.fem_linear import LockingWarning
from chainsim.tools.study.fem_nonlinear import solve_neohookean

HELP = "surface models on a clamped 40 mm tissue sheet, lifted at its centre, against a neo-Hookean slab FEM"
logger = logging.getLogger(__name__)

SIDE_MM, THICK_MM, PATCH_MM = 40.0, 2.0, 4.0
FRAME_DT = 1.0 / 60.0
SETTLE = 0.01  # a body has settled once it stays within 1 % of the lift of its final shape
TARGET = 0.05  # as bench models: frames to come within 5 % RMS of the reference
MOVING_FRAMES, WIGGLE_MM = 20, 0.05
#: (in-plane element mm, layers through the thickness) of the reference slab, by run
MESHES = {"quick": (2.0, 2), "full": (1.0, 4)}

#: the cutting pack's top layer (assets/cutting/pack.toml, [materials.dura] and its order)
PACK = {"alpha_min": 0.7, "alpha_max": 1.6, "beta": 0.35, "relax": 3, "exact": True, "order": "schill"}
#: (model, setting, params): the surface models, SurfaceChainMail at the pack's default and around it
SETTINGS = [
    ("surface", "SurfaceChainMail, the cutting pack's (0.7-1.6, beta 0.35, relax 3, exact)", PACK),
    ("surface", "SurfaceChainMail, beta 0.2", {**PACK, "beta": 0.2}),
    ("surface", "SurfaceChainMail, beta 0.5", {**PACK, "beta": 0.5}),
    ("surface", "SurfaceChainMail, relax 0", {**PACK, "relax": 0}),
    ("surface", "SurfaceChainMail, relax 10", {**PACK, "relax": 10}),
    ("surface", "SurfaceChainMail, 0.9-1.1 (stiff in plane)", {**PACK, "alpha_min": 0.9, "alpha_max": 1.1}),
    (
        "surface",
        "SurfaceChainMail, the thesis's medium (0.8-1.2, beta 0.1, relax 0)",
        {"alpha_min": 0.8, "alpha_max": 1.2, "beta": 0.1, "relax": 0},
    ),
    ("xpbd", "XPBD on triangles, substeps by rule", {"substeps": "auto"}),
    ("xpbd", "XPBD on triangles, 4 substeps", {"substeps": 4}),
    ("projective", "projective on triangles, pack default (dynamic, direct)", {"solver": "direct"}),
    ("projective", "projective on triangles, statics, direct, 10 it", {"dynamic": False, "solver": "direct"}),
    (
        "projective",
        "projective on triangles, statics, CG 20, 2 it",
        {"dynamic": False, "solver": "cg", "iterations": 2},
    ),
]
BASELINES = ("baseline: held patch only", "baseline: straight-sided cone")


@dataclass
class Sheet:
    """The slab (tetrahedra) and its mid-plane (triangles) on one in-plane grid of `n` x `n` nodes."""

    h: float
    layers: int
    thickness: float
    pos: np.ndarray  # slab nodes (mm)
    tets: np.ndarray
    fixed: np.ndarray  # slab: the four side faces
    grabbed: np.ndarray  # slab: the patch, through the thickness
    mid: np.ndarray  # slab ids of the mid-plane nodes, in the surface's node order
    surf: np.ndarray  # the surface's nodes (mm): the slab's mid-plane
    tris: np.ndarray
    surf_fixed: np.ndarray
    surf_grabbed: np.ndarray

    @property
    def n(self) -> int:
        return int(round(SIDE_MM / self.h)) + 1

    def interpolate(self, u_mid: np.ndarray, points: np.ndarray) -> np.ndarray:
        """A mid-surface field (surface node order) at in-plane `points` (mm), bilinear on the grid."""
        axis = np.arange(self.n) * self.h
        grid = u_mid.reshape(self.n, self.n, 3).transpose(1, 0, 2)  # [i (x), j (y)]
        pts = np.clip(points[:, :2], 0.0, axis[-1])
        return np.stack([RegularGridInterpolator((axis, axis), grid[..., c])(pts) for c in range(3)], axis=1)


def sheet(h: float, layers: int, thickness: float = THICK_MM, side: float = SIDE_MM) -> Sheet:
    """The sheet at in-plane spacing `h` mm with `layers` (even) tetrahedra through `thickness` mm."""
    n = int(round(side / h)) + 1
    pos, tets, _ = meshgen.tet_grid(n, n, layers + 1, spacing=1.0)
    pos = pos * [h, h, thickness / layers]  # a positive scaling keeps every tetrahedron's orientation
    c = side / 2

    def edge_and_patch(p):
        edge = (p[:, 0] < 1e-9) | (p[:, 1] < 1e-9) | (p[:, 0] > side - 1e-9) | (p[:, 1] > side - 1e-9)
        patch = np.all(np.abs(p[:, :2] - c) <= PATCH_MM / 2 + 1e-9, axis=1)
        return np.flatnonzero(edge), np.flatnonzero(patch)

    fixed, grabbed = edge_and_patch(pos)
    mid = (layers // 2) * n * n + np.arange(n * n)  # tet_grid's ids: i + n (j + n k)
    surf = pos[mid]
    _, tris, _ = meshgen.triangulated_grid(n, n)  # the same i + n j numbering
    s_fixed, s_grabbed = edge_and_patch(surf)
    return Sheet(h, layers, thickness, pos, tets, fixed, grabbed, mid, surf, tris, s_fixed, s_grabbed)


def reference(s: Sheet, E: float, nu: float, lifts) -> dict[float, np.ndarray]:
    """The neo-Hookean slab's mid-surface displacement (mm, surface node order) at each lift, along one
    load path; raises UserError if the path fails (no reference rather than a wrong one)."""
    c = np.unique(np.concatenate([s.fixed, s.grabbed]))
    top = max(lifts)
    disp = np.zeros((len(c), 3))
    disp[np.isin(c, s.grabbed), 2] = top
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LockingWarning)  # nu 0.45 is measured on purpose
        res = solve_neohookean(s.pos * 1e-3, s.tets, E, nu, c, disp * 1e-3, fractions=[x / top for x in lifts])
    if res.status != "converged":
        raise UserError(f"the neo-Hookean reference on {len(s.pos)} nodes did not converge ({res.status})")
    return {x: res.u[x / top][s.mid] * 1e3 for x in lifts}


def baselines(s: Sheet, lift: float) -> dict[str, np.ndarray]:
    """Only the held patch moves; every node rises by lift x d_edge / (d_edge + d_patch) (a cone)."""
    patch = np.zeros_like(s.surf)
    patch[s.surf_grabbed, 2] = lift
    d_f = cKDTree(s.surf[s.surf_fixed]).query(s.surf)[0]
    d_g = cKDTree(s.surf[s.surf_grabbed]).query(s.surf)[0]
    cone = np.zeros_like(s.surf)
    cone[:, 2] = lift * d_f / np.maximum(d_f + d_g, 1e-300)
    return dict(zip(BASELINES, (patch, cone)))


def _body(s: Sheet, model: str, params: dict, E: float, nu: float):
    kw = dict(params)
    if model != "surface":
        kw.update(E=E, nu=nu, unit=1e-3, thickness=s.thickness)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # settings under XPBD's substep rule are measured on purpose
        return make_body(model, s.surf, triangles=s.tris, fixed=s.surf_fixed, **kw)


def _frame(body) -> float:
    t0 = time.thread_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        body.step(FRAME_DT)
    return time.thread_time() - t0


def hold(s: Sheet, model: str, params: dict, E: float, nu: float, lift: float, frames: int):
    """A body from rest holding `lift` for `frames` frames, then moving +-WIGGLE_MM a frame: the
    displacements of the held frames (frames, N, 3), the first frame's ms and the moving frames' median ms."""
    body = _body(s, model, params, E, nu)
    target = s.surf[s.surf_grabbed] + [0.0, 0.0, lift]
    t0 = time.thread_time()
    body.grab(s.surf_grabbed, target)
    _frame(body)
    first = time.thread_time() - t0  # the grab and its frame
    shapes = [body.positions - s.surf]
    for _ in range(frames - 1):
        _frame(body)
        shapes.append(body.positions - s.surf)
    moving = []
    for f in range(MOVING_FRAMES):
        body.grab(s.surf_grabbed, target + [0.0, 0.0, WIGGLE_MM * (1 if f % 2 == 0 else -1)])
        moving.append(_frame(body))
    return np.array(shapes), 1e3 * first, 1e3 * float(np.median(moving))


def _errors(u, ref, lift: float) -> tuple[float, float, int]:
    e = np.linalg.norm(u - ref, axis=1) / lift
    return float(np.sqrt(np.mean(e**2))), float(e.max()), int(np.argmax(e))


def measure(s: Sheet, refs: dict, model: str, setting: str, params: dict, E: float, nu: float, frames: int) -> dict:
    """One setting's row: for each lift the error it ends at, its worst node, the frames to settle and to
    come within 5 % of the reference; the first frame's and the moving frames' ms."""
    warm = _body(s, model, params, E, nu)  # compilation and any factorisation outside the timing
    warm.grab(s.surf_grabbed, s.surf[s.surf_grabbed] + [0.0, 0.0, 1.0])
    _frame(warm)
    row: dict[str, Any] = {"model": model, "setting": setting, "params": params, "lifts": {}}
    firsts, movings = [], []
    for lift, ref in refs.items():
        shapes, first_ms, moving_ms = hold(s, model, params, E, nu, lift, frames)
        firsts.append(first_ms)
        movings.append(moving_ms)
        rms, worst, node = _errors(shapes[-1], ref, lift)
        per_frame = [_errors(u, ref, lift)[0] for u in shapes]
        drift = np.sqrt(np.mean(np.sum((shapes - shapes[-1]) ** 2, axis=2), axis=1)) / lift
        unsettled = np.flatnonzero(drift > SETTLE)
        within = [f + 1 for f, r in enumerate(per_frame) if r <= TARGET]
        row["lifts"][str(lift)] = {
            "rms_error": rms,
            "worst_error": worst,
            "worst_node_mm": [round(float(v), 3) for v in s.surf[node, :2]],
            "frames_to_settle": int(unsettled[-1] + 2) if len(unsettled) else 1,
            "frames_to_5_percent": within[0] if within else None,
            "first_frame_ms": first_ms,
        }
    row["first_frame_ms"] = float(np.median(firsts))
    row["ms_per_frame"] = float(np.median(movings))
    # the cost with one grabbed element (the cutting trainer's grasping tool holds one): ChainMail's normal band
    # does work per grabbed element
    one = dataclasses.replace(s, surf_grabbed=s.surf_grabbed[[len(s.surf_grabbed) // 2]])  # the centre
    row["ms_per_frame_one_element"] = hold(one, model, params, E, nu, max(refs), 1)[2]
    return row


def baseline_rows(s: Sheet, refs: dict) -> list[dict]:
    rows = []
    for name in BASELINES:
        row: dict[str, Any] = {"model": "baseline", "setting": name, "params": {}, "lifts": {}, "ms_per_frame": None}
        for lift, ref in refs.items():
            rms, worst, node = _errors(baselines(s, lift)[name], ref, lift)
            row["lifts"][str(lift)] = {
                "rms_error": rms,
                "worst_error": worst,
                "worst_node_mm": [round(float(v), 3) for v in s.surf[node, :2]],
            }
        rows.append(row)
    return rows


def add_arguments(p) -> None:
    p.add_argument(
        "--quick",
        action="store_true",
        help="the reference on a 2 mm slab of 2 layers (1,323 nodes; about 10 s in all) instead of a 1 mm slab "
        "of 4 layers (8,405 nodes; under a minute)",
    )
    p.add_argument("--E", type=float, default=1e4, help="Young's modulus in Pa (1e3..1e6, default 10 kPa)")
    p.add_argument("--nu", type=float, default=0.45, help="Poisson's ratio (0..0.49)")
    p.add_argument("--lifts", default="2,4,6", help="comma-separated lifts of the patch in mm (each 0.1..10)")
    p.add_argument("--frames", type=int, default=120, help="frames each body holds a lift (1..2000)")
    p.add_argument("--out", default="runs/bench-sheet", help="folder for results.json, results.md and the plot")


def parse_lifts(text: str) -> list[float]:
    """The --lifts list: 1 to 5 distinct lifts in 0.1..10 mm, ascending."""
    try:
        lifts = sorted({float(x) for x in text.split(",") if x.strip()})
    except ValueError:
        raise UserError(f"--lifts: expected numbers in mm separated by commas, got {text!r}") from None
    if not 1 <= len(lifts) <= 5 or not all(0.1 <= x <= 10.0 for x in lifts):
        raise UserError(f"--lifts: expected 1 to 5 lifts, each 0.1..10 mm, got {text!r}")
    return lifts


def check_args(args) -> list[float]:
    if not (1e3 <= args.E <= 1e6) or not (0.0 <= args.nu <= 0.49):
        raise UserError(f"--E / --nu: expected 1e3..1e6 Pa and 0..0.49, got {args.E:g} and {args.nu:g}")
    if not (1 <= args.frames <= 2000):
        raise UserError(f"--frames: expected 1..2000, got {args.frames}")
    return parse_lifts(args.lifts)


def study(h: float, layers: int, E: float, nu: float, lifts, frames: int, settings=None) -> dict:
    """The reference and its coarsened check, every setting's row and the baselines, as one dict."""
    s = sheet(h, layers)
    coarse = sheet(2 * h, max(2, layers // 2))
    t0 = time.perf_counter()
    logger.info(f"sheet   reference: neo-Hookean FEM on {len(s.pos)} nodes, {len(s.tets)} tetrahedra")
    refs = reference(s, E, nu, lifts)
    ref_s = time.perf_counter() - t0
    logger.info(f"sheet   discretisation check: the slab coarsened to {len(coarse.pos)} nodes")
    check = reference(coarse, E, nu, lifts)
    disc = {}
    for lift in lifts:  # the coarse slab's mid-surface against the fine one's at the coarse nodes
        fine_at = s.interpolate(refs[lift], coarse.surf)
        disc[str(lift)] = dict(zip(("rms_error", "worst_error"), _errors(check[lift], fine_at, lift)[:2]))
    rows = []
    for model, name, params in progress(settings or SETTINGS, desc="sheet settings", unit="setting"):
        rows.append(measure(s, refs, model, name, params, E, nu, frames))
    rows += baseline_rows(s, refs)
    floor = {x: min(r["lifts"][str(x)]["rms_error"] for r in rows if r["model"] == "baseline") for x in lifts}
    for r in rows:
        if r["model"] != "baseline":
            r["beats_baselines"] = all(r["lifts"][str(x)]["rms_error"] < floor[x] for x in lifts)
    return {
        "scene": f"{SIDE_MM:g} x {SIDE_MM:g} mm sheet {THICK_MM:g} mm thick, edges clamped, a {PATCH_MM:g} mm "
        f"patch lifted; E = {E:g} Pa, nu = {nu:g}",
        "reference": {
            "element_mm": h,
            "layers": layers,
            "slab_nodes": len(s.pos),
            "tets": len(s.tets),
            "seconds": ref_s,
            "check_element_mm": coarse.h,
            "check_layers": coarse.layers,
            "check_nodes": len(coarse.pos),
            "coarse_against_reference": disc,
        },
        "surface_nodes": len(s.surf),
        "triangles": len(s.tris),
        "lifts_mm": list(lifts),
        "frames": frames,
        "rows": rows,
    }


def run(args) -> int:
    lifts = check_args(args)
    h, layers = MESHES["quick" if args.quick else "full"]
    numba.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    info = study(h, layers, args.E, args.nu, lifts, args.frames)
    info["load_average"] = os.getloadavg()
    info["command"] = (
        f"chainsim bench sheet{' --quick' if args.quick else ''} --E {args.E:g} --nu {args.nu:g} "
        f"--lifts {args.lifts} --frames {args.frames} --out {args.out}"
    )
    (out / "results.json").write_text(json.dumps(info, indent=1))
    md = markdown(info)
    (out / "results.md").write_text("\n".join(md) + "\n")
    plot(info, out / "speed_accuracy.png")
    print("\n".join(md))
    return 0


def markdown(info: dict) -> list[str]:
    ref, lifts = info["reference"], info["lifts_mm"]
    big = str(lifts[-1])
    disc = ", ".join(f"{x:g} mm: {ref['coarse_against_reference'][str(x)]['rms_error']:.3f}" for x in lifts)
    md = [
        f"{info['scene']}; `{info['command']}`, one thread, load average {info['load_average'][0]:.1f}.",
        "",
        f"Reference: neo-Hookean P1 FEM on a slab of {ref['element_mm']:g} mm in-plane elements, {ref['layers']} "
        f"through the thickness ({ref['slab_nodes']} nodes, {ref['tets']} tetrahedra, {ref['seconds']:.0f} s). "
        f"Its discretisation check: the slab at {ref['check_element_mm']:g} mm, {ref['check_layers']} layers "
        f"({ref['check_nodes']} nodes) differs from it by RMS / lift {disc} (the reference's own error is about "
        f"that or less). Models: the {info['surface_nodes']} mid-plane nodes ({info['triangles']} triangles), "
        f"each lift held {info['frames']} frames from rest.",
        "",
        "| setting | ms/frame (tool moving) | one element grabbed | first frame ms | "
        + " | ".join(f"RMS / lift at {x:g} mm" for x in lifts)
        + f" | worst node at {lifts[-1]:g} mm (x, y mm) | frames to settle | frames to 5 % | beats baselines |",
        "|---|---:|---:|---:|" + "---:|" * len(lifts) + "---|---:|---:|---|",
    ]
    for r in info["rows"]:
        L = r["lifts"]
        ms = "-" if r["ms_per_frame"] is None else f"{r['ms_per_frame']:.2f}"
        ms1 = "-" if r["model"] == "baseline" else f"{r['ms_per_frame_one_element']:.2f}"
        first = "-" if r["model"] == "baseline" else f"{r['first_frame_ms']:.1f}"
        settle = "-" if r["model"] == "baseline" else str(max(L[str(x)]["frames_to_settle"] for x in lifts))
        near = [L[str(x)].get("frames_to_5_percent") for x in lifts]
        within = "-" if r["model"] == "baseline" else ("no" if None in near else str(max(near)))
        beats = "-" if r["model"] == "baseline" else ("yes" if r["beats_baselines"] else "no")
        errs = " | ".join(f"{L[str(x)]['rms_error']:.3f}" for x in lifts)
        w = L[big]
        md.append(
            f"| {r['setting']} | {ms} | {ms1} | {first} | {errs} | {w['worst_error']:.2f} at "
            f"({w['worst_node_mm'][0]:g}, {w['worst_node_mm'][1]:g}) | {settle} | {within} | {beats} |"
        )
    return md


def plot(info: dict, path: Path) -> None:
    """RMS / lift (mean over the lifts) against ms per frame, one point per setting; baselines as lines."""
    matplotlib.use("Agg")
    lifts = [str(x) for x in info["lifts_mm"]]
    fig, ax = plt.subplots(figsize=(8, 5.5))
    marks = {"surface": "o", "xpbd": "s", "projective": "^"}
    floors = []
    for r in info["rows"]:
        err = float(np.mean([r["lifts"][x]["rms_error"] for x in lifts]))
        if r["model"] == "baseline":
            floors.append((r["setting"], err))
        else:
            ax.scatter(max(r["ms_per_frame"], 1e-3), err, marker=marks[r["model"]], label=r["setting"])
    ax.set_xscale("log")
    for name, err in floors:  # a no-physics shape: the error a model must beat (drawn once the axes are set)
        ax.axhline(err, ls="--", lw=1, color="grey")
        ax.text(ax.get_xlim()[0], err, " " + name, va="bottom", fontsize=7, color="grey")
    ax.set_xlabel("CPU ms per frame, tool moving (one thread)")
    ax.set_ylabel("RMS error / lift (mean over the lifts)")
    ax.set_title("Surface models against the neo-Hookean slab:\n" + info["scene"], fontsize=8)
    ax.legend(fontsize=6, loc="best")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

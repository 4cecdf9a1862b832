"""The speed-accuracy trade where tissue lives (thesis 6.2 extended to surgical scale): a 30 x 30 x 20 mm
block of tetrahedra of 5 to 0.6 mm, base fixed, a 6 x 6 mm patch of its top held by a tool and lifted
3 mm, at 60 Hz, for soft (1 kPa: brain, fat), muscle-like (30 kPa) and skin-like (100 kPa) tissue.

Every live setting (ChainMail, XPBD, projective dynamics, the hybrid body) runs through the body API from rest for a
fixed number of frames, as a tool holds tissue in the simulator; a row keeps the median CPU per frame
and two errors of the shape it reached (RMS over nodes / the 3 mm lift):

- solver error: against the converged neo-Hookean P1 FEM on the same mesh (how far the model is from
  the solution its mesh allows);
- physical error: against the neo-Hookean FEM on the next finer mesh, interpolated (the mesh's own
  discretisation error included); on the finest mesh, where no finer one is solved, the solver error
  plus the next coarser mesh's discretisation error divided by four (P1 displacements converge as h^2),
  marked "estimated"; on a mesh too large for the FEM, against the coarser mesh's FEM interpolated (also
  marked: that reference's own discretisation error is the floor of what such a row can score).

The table `model = "auto"` reads (`assets/presets/models.toml`) is written from these rows.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.interpolate import RegularGridInterpolator
from scipy.spatial import cKDTree

from chainsim.systems.engine.bodies.chainmail import ChainMailBody
from chainsim.systems.engine.bodies.factory import make_body
from chainsim.systems.engine.bodies.xpbd import XPBDBody
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.meshgen import tet_grid

from .fem_linear import LockingWarning
from .fem_nonlinear import solve_neohookean

logger = logging.getLogger(__name__)

FRAME_DT = 1.0 / 60.0
BLOCK_MM = (30.0, 30.0, 20.0)
PATCH_MM = 6.0
LIFT_MM = 3.0
#: element sizes (mm) by run
SIZES = {"quick": [5.0, 2.5], "full": [5.0, 2.5, 1.25, 0.625]}
#: (name, E Pa, nu)
MATERIALS = [("soft", 1e3, 0.45), ("muscle", 3e4, 0.45), ("skin", 1e5, 0.49)]
QUICK_MATERIALS = [("muscle", 3e4, 0.45)]
FRAMES = 30  # half a second of holding
NL_LIMIT = 12_000  # the neo-Hookean reference is solved up to this many nodes
DIRECT_LIMIT = 20_000  # the direct projective solve is not factorised above this many nodes here
SLOW_FRAME_S = 8.0  # a setting whose first frame takes longer is timed on that frame only

#: the live settings: (model, name, params)
SETTINGS: list[tuple[str, str, dict[str, Any]]] = [
    ("chainmail", "ChainMail thesis-medium r0", {"alpha_min": 0.8, "alpha_max": 1.2, "beta": 0.1, "relax": 0}),
    ("chainmail", "ChainMail thesis-medium r4", {"alpha_min": 0.8, "alpha_max": 1.2, "beta": 0.1, "relax": 4}),
    (
        "chainmail",
        "ChainMail soft-tissue r4",
        {"alpha_min": 0.841577, "alpha_max": 1.08347, "beta": 0.074934, "relax": 4},
    ),
    ("xpbd", "XPBD, 1 substep", {"substeps": 1}),
    ("xpbd", "XPBD, 4 substeps", {"substeps": 4}),
    ("xpbd", "XPBD, substeps by rule", {"substeps": "auto"}),
    ("projective", "projective statics, direct, 10 it", {"dynamic": False, "solver": "direct", "iterations": 10}),
    (
        "projective",
        "projective statics, CG 6, 1 it",
        {"dynamic": False, "solver": "cg", "cg_iterations": 6, "iterations": 1, "rotation_iterations": 1},
    ),
    ("projective", "projective statics, CG 20, 2 it", {"dynamic": False, "solver": "cg", "iterations": 2}),
    (
        "hybrid",
        "hybrid, linear start, CG 6, 3 rotations",
        {"coarse": "auto", "cg_iterations": 6, "rotation_iterations": 3, "start": "linear"},
    ),
    (
        "hybrid",
        "hybrid, linear start, CG 3, 2 rotations",
        {"coarse": "auto", "cg_iterations": 3, "rotation_iterations": 2, "start": "linear"},
    ),
]


@dataclass
class Block:
    spacing: float
    shape: tuple[int, int, int]
    pos: np.ndarray
    tets: np.ndarray
    fixed: np.ndarray
    grabbed: np.ndarray

    @property
    def constrained(self) -> np.ndarray:
        return np.unique(np.concatenate([self.fixed, self.grabbed]))

    def interpolate(self, u: np.ndarray, points: np.ndarray) -> np.ndarray:
        nx, ny, nz = self.shape
        axes = [np.arange(m) * self.spacing for m in (nx, ny, nz)]
        grid = u.reshape(nz, ny, nx, 3).transpose(2, 1, 0, 3)
        pts = np.clip(points, 0.0, [a[-1] for a in axes])
        return np.stack([RegularGridInterpolator(axes, grid[..., c])(pts) for c in range(3)], axis=1)


def block(spacing: float, size_mm: tuple[float, float, float] = BLOCK_MM) -> Block:
    """A size_mm block of tetrahedra `spacing` mm apart, fixed at the bottom, with the PATCH_MM square at the
    top centre grabbed."""
    nx, ny, nz = (int(round(s / spacing)) + 1 for s in size_mm)
    shape = (nx, ny, nz)
    pos, tets, _ = tet_grid(nx, ny, nz, spacing=spacing)
    fixed = np.flatnonzero(pos[:, 2] < 1e-9)
    cx, cy = size_mm[0] / 2, size_mm[1] / 2
    top = (pos[:, 2] > size_mm[2] - 1e-9) & (np.abs(pos[:, 0] - cx) <= PATCH_MM / 2 + 1e-9)
    grabbed = np.flatnonzero(top & (np.abs(pos[:, 1] - cy) <= PATCH_MM / 2 + 1e-9))
    return Block(spacing, shape, pos, tets, fixed, grabbed)


def reference(b: Block, E: float, nu: float, lift_mm: float = LIFT_MM, limit: int = NL_LIMIT) -> np.ndarray | None:
    """The neo-Hookean P1 static displacement (mm) of a lift, or None above `limit` nodes."""
    if len(b.pos) > limit:
        return None
    c = b.constrained
    disp = np.zeros((len(c), 3))
    disp[np.isin(c, b.grabbed), 2] = lift_mm
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LockingWarning)
        res = solve_neohookean(b.pos * 1e-3, b.tets, E, nu, c, disp * 1e-3)
    if 1.0 not in res.u:  # the load path did not converge: no reference rather than a wrong one
        logger.warning(f"neo-Hookean reference on {len(b.pos)} nodes did not converge ({res.status})")
        return None
    return res.u[1.0] * 1e3


def run_setting(b: Block, model: str, params: dict, E: float, nu: float) -> tuple[np.ndarray | None, dict]:
    """Hold the lift for FRAMES frames from rest; the displacement reached and the cost per frame."""
    kw = dict(params)
    if params.get("solver") == "direct" and len(b.pos) > DIRECT_LIMIT:
        return None, {
            "ms_per_frame": float("nan"),
            "status": f"not run: direct factorisation above {DIRECT_LIMIT} nodes",
        }
    if model != "chainmail":
        kw.update(E=E, nu=nu, unit=1e-3)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # under-resolved settings are measured on purpose
            body = make_body(model, b.pos, tets=b.tets, fixed=b.fixed, **kw)
            target = b.pos[b.grabbed] + [0.0, 0.0, LIFT_MM]
            body.grab(b.grabbed, target)
            times = []
            for f in range(FRAMES):
                t0 = time.thread_time()
                if isinstance(body, ChainMailBody):  # ChainMail moves to the target; the others step towards it
                    body.move(b.grabbed, target)
                else:
                    body.step(FRAME_DT)
                times.append(time.thread_time() - t0)
                if f == 1 and times[0] + times[1] > SLOW_FRAME_S:
                    # too slow to hold for long: the cost is the second (warm) frame's, the error not measured
                    why = f"timed on frame 2 (first {times[0]:.1f} s)"
                    return None, {"ms_per_frame": 1e3 * times[1], "first_frame_ms": 1e3 * times[0], "status": why}
    except UserError as e:
        return None, {"ms_per_frame": float("nan"), "status": f"refused: {e}"}
    warm = times[1:] or times
    info = {"ms_per_frame": 1e3 * float(np.median(warm)), "first_frame_ms": 1e3 * times[0], "status": "ran"}
    if isinstance(body, XPBDBody):
        info["substeps"] = int(body.substeps)
    return body.positions - b.pos, info


def baselines(b: Block) -> dict[str, np.ndarray]:
    """Two shapes no physics makes, the floor a model must beat for its error to mean anything: only
    the held patch moves; every node moves by d_fixed / (d_fixed + d_held) of the lift."""
    patch = np.zeros_like(b.pos)
    patch[b.grabbed, 2] = LIFT_MM
    d_f = cKDTree(b.pos[b.fixed]).query(b.pos)[0]
    d_g = cKDTree(b.pos[b.grabbed]).query(b.pos)[0]
    blend = np.zeros_like(b.pos)
    blend[:, 2] = LIFT_MM * d_f / np.maximum(d_f + d_g, 1e-300)
    return {"baseline: held patch only": patch, "baseline: distance blend": blend}


def volume_figures(b: Block, u: np.ndarray) -> dict:
    """Total volume change and the smallest tetrahedron volume ratio of a displacement (mm)."""

    def signed(x):
        p = x[b.tets]
        return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0])

    v0 = signed(b.pos)
    ratio = signed(b.pos + u) / v0
    return {"volume_change": float(np.sum(ratio * np.abs(v0)) / np.sum(np.abs(v0)) - 1.0), "min_J": float(ratio.min())}


def _rms(u, ref) -> float:
    return float(np.sqrt(np.mean(np.sum((u - ref) ** 2, axis=1))) / LIFT_MM)


def run(mode: str = "quick", progress=None) -> dict:
    sizes = SIZES[mode]
    materials = MATERIALS if mode == "full" else QUICK_MATERIALS
    blocks = [block(h) for h in sizes]
    rows: list[dict] = []
    refs_info = []
    for name, E, nu in materials:
        refs: list[np.ndarray | None] = []
        for b in blocks:
            t0 = time.perf_counter()
            refs.append(reference(b, E, nu))
            refs_info.append({"material": name, "nodes": len(b.pos), "seconds": time.perf_counter() - t0})
        for k, b in enumerate(blocks):
            ref = refs[k]
            finer, finer_ref = (blocks[k + 1], refs[k + 1]) if k + 1 < len(blocks) else (None, None)
            phys = finer.interpolate(finer_ref, b.pos) if finer is not None and finer_ref is not None else None
            disc = None
            if ref is not None and phys is not None:
                disc = _rms(ref, phys)  # this mesh's own discretisation error
            runs = [(m, s_, p) for m, s_, p in SETTINGS] + [("baseline", s_, {}) for s_ in baselines(b)]
            for model, setting, params in runs:
                if progress:
                    progress(f"{name} {len(b.pos)} nodes: {setting}")
                if model == "baseline":
                    u, info = baselines(b)[setting], {"ms_per_frame": float("nan"), "status": "no physics"}
                else:
                    u, info = run_setting(b, model, params, E, nu)
                row = {
                    "scene": "tissue-block",
                    "material": name,
                    "E": E,
                    "nu": nu,
                    "element_mm": b.spacing,
                    "nodes": len(b.pos),
                    "tets": len(b.tets),
                    "model": model,
                    "setting": setting,
                    "params": params,
                    **info,
                }
                if u is not None:
                    row.update(volume_figures(b, u))
                if ref is not None:
                    row["reference_volume_change"] = volume_figures(b, ref)["volume_change"]
                if u is not None and ref is not None:
                    row["solver_error"] = _rms(u, ref)
                if u is not None and phys is not None:
                    row["physical_error"] = _rms(u, phys)
                elif (
                    u is not None
                    and ref is not None
                    and k > 0
                    and (coarse_disc := blocks_disc(rows, name, blocks[k - 1]))
                ):
                    row["physical_error"] = row["solver_error"] + coarse_disc / 4.0
                    row["physical_estimated"] = True
                elif u is not None and k > 0 and (coarse := refs[k - 1]) is not None:
                    # no FEM on this mesh (too large): against the coarser mesh's FEM, interpolated, whose own
                    # discretisation error bounds how well this can score
                    coarse_ref = blocks[k - 1].interpolate(coarse, b.pos)
                    row["physical_error"] = _rms(u, coarse_ref)
                    row["physical_estimated"] = True
                    row["reference"] = f"FEM on {len(blocks[k - 1].pos)} nodes, interpolated"
                if disc is not None:
                    row["mesh_error"] = disc
                rows.append(row)
            # a model row means something only where it beats both no-physics shapes on that mesh
            here = [r for r in rows if r["material"] == name and r["nodes"] == len(b.pos)]
            floor = min(
                (r["physical_error"] for r in here if r["model"] == "baseline" and "physical_error" in r), default=None
            )
            for r in here:
                if r["model"] != "baseline" and floor is not None and "physical_error" in r:
                    r["beats_baselines"] = bool(r["physical_error"] < floor)
    return {"mode": mode, "frames": FRAMES, "lift_mm": LIFT_MM, "rows": rows, "references": refs_info}


def blocks_disc(rows: list[dict], material: str, coarser: Block) -> float | None:
    """The discretisation error measured on the next coarser mesh (from its rows)."""
    for r in rows:
        if r["material"] == material and r["element_mm"] == coarser.spacing and "mesh_error" in r:
            return float(r["mesh_error"])
    return None


def model_table(results: dict) -> dict:
    """The rows `auto` chooses from: physical error and ms per frame of every setting that ran."""
    out = []
    for r in results["rows"]:
        if r["model"] == "baseline":
            continue
        err = r.get("physical_error", r.get("solver_error"))
        if err is None or not np.isfinite(r["ms_per_frame"]):
            continue
        out.append(
            {
                "scene": r["scene"],
                "nodes": r["nodes"],
                "E": r["E"],
                "model": r["model"],
                "setting": r["setting"],
                "params": r["params"],
                "beats_baselines": bool(r.get("beats_baselines", True)),
                "rms_error": float(err),
                "solver_error": float(r.get("solver_error", float("nan"))),
                "ms_per_update": float(r["ms_per_frame"]),
            }
        )
    return {"strain": LIFT_MM / BLOCK_MM[2], "rows": out}

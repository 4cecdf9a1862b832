"""Making a body by model name, and choosing a model for a budget from the study's table.

`make_body(model, rest, tets=..., triangles=..., **settings)` builds any of the models through the body
API, its settings checked against the one declaration of each model's parameters (model_params);
`choose_model(...)` reads the speed-accuracy table the study writes (thesis 6.2 extended) and picks
the cheapest model and setting that meets an error and/or time budget for the nearest scene and mesh
size, saying why.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from chainsim.systems.engine import meshgen, model_params
from chainsim.systems.engine.bodies.base import Body, Cells
from chainsim.systems.engine.bodies.chainmail import ChainMailBody
from chainsim.systems.engine.bodies.hybrid import HybridBody
from chainsim.systems.engine.bodies.projective import ProjectiveBody
from chainsim.systems.engine.bodies.surface import SurfaceChainMailBody
from chainsim.systems.engine.bodies.xpbd import XPBDBody
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels.graph import Graph

MODELS = model_params.MODELS


def make_body(
    model: str,
    rest: ArrayLike,
    *,
    tets: Cells | None = None,
    triangles: Cells | None = None,
    fixed: ArrayLike | None = None,
    links: Cells | Graph | None = None,
    **settings: object,
) -> Body:
    """A body of `model` on `tets` (or surface `triangles`). `settings` are any of the model's parameters
    (chainsim.systems.engine.model_params: each is checked against its declaration; ones the model does
    not take are left out, so one set of settings builds any model). ChainMail runs on `links` (default:
    the cells' edges) and, like SurfaceChainMail, takes alpha_min, alpha_max and beta as numbers or as
    arrays of one value per link, handed to the body's kernels as they are."""
    kw = model_params.settings(model_params.model_name(model), settings)
    has_tets = tets is not None and len(tets) > 0
    if model == "chainmail":
        if links is None:
            cells = tets if has_tets else triangles
            if cells is None or len(cells) == 0:
                raise UserError("a ChainMail body needs tetrahedra or triangles (its links are their edges)")
            links = meshgen.links_from_cells(np.asarray(cells, dtype=np.int64))
        return ChainMailBody(rest, links, fixed=fixed, **kw)
    if model == "xpbd":
        return XPBDBody(rest, tets if has_tets else None, None if has_tets else triangles, fixed=fixed, **kw)
    if model == "projective":
        return ProjectiveBody(rest, tets if has_tets else None, None if has_tets else triangles, fixed=fixed, **kw)
    if model == "hybrid":  # HybridBody refuses a mesh without tetrahedra
        return HybridBody(rest, tets if has_tets else None, fixed=fixed, **kw)
    # SurfaceChainMail on a sheet's triangles (thesis 4.4)
    if has_tets or triangles is None or len(triangles) == 0:
        raise UserError("a surface ChainMail body needs a triangle surface (volumes: chainmail or hybrid)")
    return SurfaceChainMailBody(rest, triangles, fixed=fixed, **kw)


#: the hybrid body's settings (a table row may give any of them)
HYBRID_PARAMS = (
    "iterations",
    "cg_iterations",
    "rotation_iterations",
    "coarse",
    "start",
    "sleep",
    "wake_rings",
)
#: the settings a table row may give for each model: the body built is exactly the row's
ROW_PARAMS = {
    "chainmail": ("alpha_min", "alpha_max", "beta", "relax"),
    "xpbd": ("substeps", "iterations", "constraints", "damping"),
    "projective": ("iterations", "dynamic", "solver", "cg_iterations", "rotation_iterations", "damping"),
    "hybrid": HYBRID_PARAMS,
}
#: with no budget at all, `auto` keeps to one 60 Hz frame
DEFAULT_TIME_BUDGET_MS = 16.7


@dataclass
class Choice:
    model: str
    setting: str
    rms_error: float
    reason: str
    params: dict = field(default_factory=dict)


def load_table(path: Path) -> list[dict]:
    """Rows of the study's model table: scene, nodes, model, setting, params, rms_error, ms_per_update."""
    try:
        data = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise UserError(f"model table {path}: cannot read it ({e})") from None
    rows = data.get("rows", [])
    need = {"scene", "nodes", "model", "setting", "rms_error", "ms_per_update"}
    if not isinstance(rows, list) or not rows or not all(isinstance(r, dict) and need <= set(r) for r in rows):
        raise UserError(f"model table {path}: expected [[rows]] with {', '.join(sorted(need))}")
    for i, r in enumerate(rows):
        params = r.get("params", {})
        allowed = ROW_PARAMS.get(r["model"], ())
        if not isinstance(params, dict) or not set(params) <= set(allowed):
            raise UserError(f"model table {path}: rows[{i}].params: expected keys among {', '.join(allowed)}")
    return rows


def choose_model(
    table: list[dict],
    *,
    scene: str,
    nodes: int,
    error_budget: float = 0.0,
    time_budget_ms: float = 0.0,
    E: float | None = None,
) -> Choice:
    """A row of the table for a body of `nodes` nodes (and Young's modulus E where the table has several).
    Rows that do not beat the study's no-physics baselines are taken only when no other row fits.

    An error budget alone: the cheapest row that meets it. A time budget alone: the most accurate row
    that fits it. Both: the cheapest meeting both, else the most accurate that fits the time. Neither:
    the most accurate within one 60 Hz frame (DEFAULT_TIME_BUDGET_MS). Rows come from the nearest
    scene, mesh size (log scale) and stiffness; times scale linearly with the node count.
    """
    scenes = sorted({r["scene"] for r in table})
    use_scene = scene if scene in scenes else ("block" if "block" in scenes else scenes[0])
    rows = [r for r in table if r["scene"] == use_scene and r["model"] in MODELS]
    sizes = sorted({int(r["nodes"]) for r in rows})
    size = min(sizes, key=lambda s: abs(math.log(max(s, 1) / max(nodes, 1))))
    rows = [r for r in rows if int(r["nodes"]) == size]
    stiff = sorted({float(r["E"]) for r in rows if "E" in r})
    where = f"study scene '{use_scene}' at {size} nodes (this body: {nodes})"
    if stiff and E is not None:
        e_row = min(stiff, key=lambda v: abs(math.log(v / max(E, 1e-12))))
        rows = [r for r in rows if float(r.get("E", e_row)) == e_row]
        where += f", E = {e_row:g} Pa (this body: {E:g})"
    scale = max(nodes, 1) / max(size, 1)
    cand = [
        dict(r, ms=float(r["ms_per_update"]) * scale)
        for r in rows
        if np.isfinite(float(r["rms_error"])) and np.isfinite(float(r["ms_per_update"]))
    ]
    if not cand:
        raise UserError(f"model table: no measured row for {where}")
    budget = time_budget_ms or (0.0 if error_budget else DEFAULT_TIME_BUDGET_MS)
    within_time = [r for r in cand if not budget or r["ms"] <= budget]
    # a row no better than a no-physics shape (the study's baselines) is taken only when nothing else fits
    meaningful = [r for r in within_time if r.get("beats_baselines", True)]
    if meaningful:
        within_time = meaningful
    else:
        where += "; no row within the budget beats the no-physics baselines"
    ok = [r for r in within_time if not error_budget or float(r["rms_error"]) <= error_budget]
    limits = f"error <= {error_budget or 'any'}, time <= {budget or 'any'} ms"
    if error_budget and ok:
        best = min(ok, key=lambda r: (r["ms"], float(r["rms_error"])))
        why = f"the cheapest meeting {limits} on {where}"
    elif within_time:
        best = min(within_time, key=lambda r: (float(r["rms_error"]), r["ms"]))
        miss = f"nothing meets error <= {error_budget}: " if error_budget else ""
        why = f"{miss}the most accurate within {budget} ms on {where}"
    else:
        best = min(cand, key=lambda r: r["ms"])
        why = f"nothing fits {budget} ms: the fastest on {where}"
    return Choice(best["model"], str(best["setting"]), float(best["rms_error"]), why, dict(best.get("params", {})))

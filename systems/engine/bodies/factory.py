"""Making a body by model name, and choosing a model for a budget from the study's table.

`make_body("xpbd" | "projective", rest, tets=..., triangles=..., **settings: float)` builds one through the
body API; `choose_model(...)` reads the speed-accuracy table the study writes (thesis 6.2 extended)
and picks the cheapest model and setting that meets an error and/or time budget for the nearest
scene and mesh size, saying why.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from chainsim.engine.bodies.base import Body
from chainsim.engine.bodies.projective import ProjectiveBody
from chainsim.engine.bodies.xpbd import XPBDBody
from chainsim.engine.errors import UserError

MODELS = ("chainmail", "xpbd", "projective")


def make_body(
    model: str,
    rest: ArrayLike,
    *,
    tets: ArrayLike | None = None,
    triangles: ArrayLike | None = None,
    fixed: ArrayLike | None = None,
    **settings: float | str | bool,
) -> Body:
    """An XPBD or projective-dynamics body on `tets` (or, for XPBD, surface `triangles`)."""
    has_tets = tets is not None and len(tets) > 0
    if model == "xpbd":
        keys = ("E", "nu", "density", "damping", "substeps", "iterations", "unit", "thickness", "bending")
        kw = {k: settings[k] for k in keys if k in settings}
        return XPBDBody(rest, tets if has_tets else None, None if has_tets else triangles, fixed=fixed, **kw)
    if model == "projective":
        keys = ("E", "nu", "density", "damping", "iterations", "unit", "thickness")
        keys += ("dynamic", "solver", "cg_iterations", "rotation_iterations")
        kw = {k: settings[k] for k in keys if k in settings}
        return ProjectiveBody(rest, tets if has_tets else None, None if has_tets else triangles, fixed=fixed, **kw)
    raise UserError(f"model: expected one of {', '.join(MODELS)}, got {model!r}")


@dataclass
class Choice:
    model: str
    setting: str
    rms_error: float
    ms_per_update: float
    reason: str


def load_table(path: Path) -> list[dict]:
    """Rows of the study's model table: scene, nodes, model, setting, rms_error, ms_per_update."""
    try:
        data = tomllib.loads(Path(path).read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise UserError(f"model table {path}: cannot read it ({e})") from None
    rows = data.get("rows", [])
    need = {"scene", "nodes", "model", "setting", "rms_error", "ms_per_update"}
    if not isinstance(rows, list) or not rows or not all(isinstance(r, dict) and need <= set(r) for r in rows):
        raise UserError(f"model table {path}: expected [[rows]] with {', '.join(sorted(need))}")
    return rows


def choose_model(
    table: list[dict], *, scene: str, nodes: int, error_budget: float = 0.0, time_budget_ms: float = 0.0
) -> Choice:
    """The cheapest row meeting both budgets (0: no budget) at the nearest mesh size of the nearest scene.

    Times scale with the node count (the table's size to this mesh's, linearly). When nothing meets an
    error budget, the most accurate row within the time budget is taken and the reason says so.
    """
    scenes = sorted({r["scene"] for r in table})
    use_scene = scene if scene in scenes else ("block" if "block" in scenes else scenes[0])
    rows = [r for r in table if r["scene"] == use_scene]
    sizes = sorted({int(r["nodes"]) for r in rows})
    size = min(sizes, key=lambda s: abs(math.log(max(s, 1) / max(nodes, 1))))
    rows = [r for r in rows if int(r["nodes"]) == size and r["model"] in MODELS]
    scale = max(nodes, 1) / max(size, 1)
    cand = [dict(r, ms=float(r["ms_per_update"]) * scale) for r in rows if np.isfinite(float(r["rms_error"]))]
    within_time = [r for r in cand if not time_budget_ms or r["ms"] <= time_budget_ms]
    ok = [r for r in within_time if not error_budget or float(r["rms_error"]) <= error_budget]
    where = f"study scene '{use_scene}' at {size} nodes (this body: {nodes})"
    if ok:
        best = min(ok, key=lambda r: (r["ms"], float(r["rms_error"])))
        why = f"cheapest meeting error <= {error_budget or 'any'} and time <= {time_budget_ms or 'any'} ms on {where}"
    elif within_time:
        best = min(within_time, key=lambda r: float(r["rms_error"]))
        why = f"nothing meets error <= {error_budget}: the most accurate within {time_budget_ms or 'any'} ms on {where}"
    else:
        best = min(cand, key=lambda r: r["ms"])
        why = f"nothing fits {time_budget_ms} ms: the fastest on {where}"
    return Choice(best["model"], str(best["setting"]), float(best["rms_error"]), best["ms"], why)

"""Fit Generalised ChainMail parameters (alpha_min, alpha_max, beta of 5.2.2 and the number of
relaxation sweeps of 5.2.5) to the neo-Hookean FEM reference, and store them as named presets.

What E can and cannot do here.  Under imposed displacements the static FEM field does not depend
on Young's modulus at all (linear FEM: u scales with the prescribed values only; neo-Hookean:
the energy is proportional to E at fixed nu).  What E changes in practice is how far a tool
pushes the tissue: a given traction p moves tissue of modulus E by a strain of roughly p/E.  So
the calibration fits ChainMail at the strain level
    strain = clip(REFERENCE_TRACTION / E, MIN_STRAIN, MAX_STRAIN)
(or at an explicit --strain), for the given Poisson ratio.  ChainMail has no force input, so a
preset is only right near the strain level it was fitted at; the preset records that level.
"""

from __future__ import annotations

import itertools
import os
import tomllib
import warnings
from pathlib import Path

import numba
import numpy as np
import tomli_w
from scipy.optimize import minimize

from chainsim.assets import ASSETS_DIR
from chainsim.systems.engine import atomicfile
from chainsim.systems.engine.errors import UserError

from .chainmail_model import ChainMailModel, ChainMailParams
from .fem_linear import LockingWarning, check_material
from .fem_nonlinear import NeoHookeanFEM
from .metrics import displacement_error
from .scenes import block

REFERENCE_TRACTION = 300.0  # Pa: a gentle instrument traction (about 0.03 N over 1 cm^2)
MIN_STRAIN, MAX_STRAIN = 1e-3, 0.5
RELAX_OPTIONS = (0, 4, 16, 64)
PRESETS_PATH = ASSETS_DIR / "presets" / "materials.toml"
FIELDS = ("alpha_min", "alpha_max", "beta", "relax_iterations", "fitted_error", "source")


def strain_for(E: float | None, strain: float | None = None) -> float:
    if strain is not None:
        if not (np.isfinite(strain) and MIN_STRAIN <= strain <= MAX_STRAIN):
            raise UserError(f"--strain must lie in [{MIN_STRAIN}, {MAX_STRAIN}], got {strain}")
        return float(strain)
    if E is None:
        return 0.1
    return float(np.clip(REFERENCE_TRACTION / E, MIN_STRAIN, MAX_STRAIN))


def fit(nu: float, E: float | None = None, strain: float | None = None, n: int = 8, progress=None) -> dict:
    """Best ChainMail parameters on the study block (n^3 nodes) against neo-Hookean FEM."""

    numba.set_num_threads(1)  # many tiny relaxations: thread start-up would dominate
    check_material(E if E is not None else 1.0, nu)
    s = strain_for(E, strain)
    scene = block(n)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", LockingWarning)
        fem = NeoHookeanFEM(scene.pos, scene.tets, E or 1.0, nu, scene.constrained)
        res = fem.solve_path(scene.constrained_disp(1.0), [s])
    if res.status != "converged":
        raise UserError(f"reference FEM did not converge at strain {s:g} (nu={nu:g})")
    ref = res.u[s]
    d = s * scene.length
    cm = ChainMailModel(scene.pos, scene.links, scene.fixed)
    disp = scene.grab_disp(s)

    def err(am_slack, ratio, beta, k):
        p = ChainMailParams(max(1.0 - ratio * am_slack, 0.05), 1.0 + am_slack, beta, k)
        u, _ = cm.solve(scene.grabbed, disp, p)
        return displacement_error(u, ref, d)[0], p

    best: tuple = (np.inf, None)  # then (error, params, slack, ratio, beta factor) of the best setting
    # the stretch slack that matters scales with the strain (the cascade reaches about
    # strain / (alpha_max - 1) of the body), so search it relative to the strain level
    slacks = s * np.geomspace(0.03, 3.0, 12)
    for k, sl, ratio, bf in itertools.product(RELAX_OPTIONS, slacks, (0.5, 1.0, 2.0), (0.0, 0.25, 0.5, 1.0)):
        e, p = err(sl, ratio, bf * sl, k)
        if e < best[0]:
            best = (e, p, sl, ratio, bf)
    if progress:
        progress(f"grid search: rms {best[0]:.4f}")
    # local refinement of the continuous parameters at the best relaxation count

    e0, p0, sl0, r0, b0 = best
    k = p0.relax_iterations

    def obj(x):
        sl = s * np.exp(x[0])
        return err(sl, abs(x[1]), abs(x[2]) * sl, k)[0]

    x0 = np.array([np.log(sl0 / s), r0, b0])
    opt = minimize(obj, x0, method="Nelder-Mead", options={"maxiter": 150, "xatol": 1e-3, "fatol": 1e-5})
    if opt.fun < e0:
        sl = s * np.exp(opt.x[0])
        e0, p0 = err(sl, abs(opt.x[1]), abs(opt.x[2]) * sl, k)
    return {
        "alpha_min": round(float(p0.alpha_min), 6),
        "alpha_max": round(float(p0.alpha_max), 6),
        "beta": round(float(p0.beta), 6),
        "relax_iterations": int(p0.relax_iterations),
        "fitted_error": round(float(e0), 6),
        "source": (
            f"chainsim study calibrate: neo-Hookean FEM, nu={nu:g}"
            + (f", E={E:g} Pa" if E is not None else "")
            + f", strain {s:g}, block {scene.n_nodes} nodes, RMS error / displacement"
        ),
        "nu": float(nu),
        "E": float(E) if E is not None else None,
        "strain": s,
        "warnings": [str(w.message) for w in caught],
    }


def load_presets(path: str | os.PathLike | None = None) -> dict:
    p = Path(path) if path else PRESETS_PATH
    if not p.exists():
        return {}
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as e:
        raise UserError(f"{p}: not valid TOML ({e})") from None


def write_preset(name: str, preset: dict, path: str | os.PathLike | None = None) -> Path:
    """Add or replace table [name] in the presets file, keeping every other preset."""
    if not name or not all(ch.isalnum() or ch in "-_" for ch in name):
        raise UserError(f"--name must be letters, digits, '-' or '_', got {name!r}")
    p = Path(path) if path else PRESETS_PATH
    presets = load_presets(p)
    presets[name] = {k: preset[k] for k in FIELDS} | {
        k: preset[k] for k in ("nu", "E", "strain") if preset.get(k) is not None
    }
    lines = [
        "# ChainMail material presets written by `chainsim study calibrate` (see",
        "# docs/choosing-a-model.md). Each table: alpha_min, alpha_max, beta, relax_iterations,",
        "# fitted_error (RMS displacement error / imposed displacement vs neo-Hookean FEM) and",
        "# the fit's source; nu, E and strain record what it was fitted for.",
        "",
    ]
    text = "\n".join(lines) + "\n" + tomli_w.dumps({key: presets[key] for key in sorted(presets)})
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
        atomicfile.write_text(p, text)
    except OSError as e:
        raise UserError(f"--out {p}: cannot write ({e.strerror})") from None
    return p


# presets shipped with the project: (name, E [Pa], nu)
SHIPPED = [("bone-like", 1.0e9, 0.3), ("medium", 3.0e4, 0.4), ("soft-tissue", 3.0e3, 0.45), ("very-soft", 6.0e2, 0.49)]

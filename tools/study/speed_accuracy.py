"""The speed-accuracy study (thesis 6.2, Table 6.5 revisited): every model on every scene and
resolution, scored against the neo-Hookean FEM ground truth.

Reference field per resolution.  The nonlinear FEM is affordable only on the coarsest mesh of a
scene (SuperLU on 3-D meshes grows far faster than N).  Finer meshes use the composite reference
    u_ref = u_lin(fine) + interp(u_nl(coarse) - u_lin(coarse)),
i.e. linear FEM at the fine resolution plus the coarse mesh's nonlinear correction; the finest mesh
(where even linear FEM is out of budget) uses the interpolated reference of the mesh below.  The
report names the reference used in every row.
"""

from __future__ import annotations

import logging
import time
import warnings

import numba
import numpy as np

from chainsim.tools.study.calibrate import load_presets

from . import scenes as sc
from .chainmail_model import ChainMailModel, ChainMailParams
from .fem_linear import LinearFEM, LockingWarning
from .fem_nonlinear import NeoHookeanFEM
from .forces import reference_forces
from .live_models import LIVE, baseline_blend, baseline_patch, settle
from .mass_spring import SYMPLECTIC, MassSpring, integrate
from .metrics import displacement_error, median_time, realtime_size, volume_change

logger = logging.getLogger(__name__)

E_STUDY, NU_STUDY = 3000.0, 0.45
STRAINS = [0.01, 0.05, 0.1, 0.25, 0.5]
QUICK_STRAINS = [0.01, 0.1, 0.5]
PARETO_STRAIN = 0.1
RELAX = [0, 4, 16, 64]

# budgets (nodes): above these a solver is not run at that resolution
LIMITS = {
    "full": {"nl": 2000, "lin": 12000, "ms": 12000, "ms_explicit": 2000, "live": 12000, "force": 2000},
    "quick": {"nl": 1000, "lin": 2500, "ms": 2500, "ms_explicit": 600, "live": 600, "force": 1000},
}


def log(msg: str) -> None:
    logger.info(f"study {time.strftime('%H:%M:%S')}: {msg}")


def default_chainmail_settings():
    """Materials compared: the thesis's medium and soft objects (6.2.1, after Gibson) and the
    preset calibrated for this study's material when the presets file has it."""
    out = {"thesis-medium": ChainMailParams(0.8, 1.2, 0.1), "thesis-soft": ChainMailParams(0.5, 2.5, 0.3)}
    try:
        p = load_presets().get("soft-tissue")
        if p:
            out["soft-tissue"] = ChainMailParams(p["alpha_min"], p["alpha_max"], p["beta"])
    except Exception as e:  # a broken presets file must not stop the study
        log(f"presets not used: {e}")
    return out


def _row(scene, res_n, model, strain, u, ref, ref_name, t, iters, status, extra=None):
    d = strain * scene.length
    row = {
        "scene": scene.name,
        "resolution": res_n,
        "nodes": scene.n_nodes,
        "elements": len(scene.tets),
        "model": model,
        "strain": strain,
        "status": status,
        "time_ms": t * 1e3,
        "iterations": iters,
        "reference": ref_name,
    }
    if u is not None and ref is not None:
        rms, mx = displacement_error(u, ref, d)
        row.update({"rms_error": rms, "max_error": mx})
    if u is not None:
        row.update(volume_change(scene.pos, scene.tets, u))
    if extra:
        row.update(extra)
    return row


class _Level:
    """One resolution of a scene: its mesh, its FEM solutions and the reference every model's rows are
    scored against; rows and timings go to the study's lists."""

    def __init__(self, name, res_n, strains, repeats, rows, timings):
        self.name, self.res_n, self.strains, self.repeats = name, res_n, strains, repeats
        self.rows, self.timings = rows, timings
        self.scene = sc.SCENES[name](res_n)
        self.n = self.scene.n_nodes
        self.refs, self.lins, self.nls, self.lin_t = {}, {}, {}, {}
        self.ref_name = None
        self.lin = self.fem = None

    def add(self, model, strain, u, t, iters, status, extra=None) -> None:
        self.rows.append(
            _row(
                self.scene,
                self.res_n,
                model,
                strain,
                u,
                self.refs.get(strain),
                self.ref_name,
                t,
                iters,
                status,
                extra,
            )
        )

    def timing(self, model, seconds, **extra) -> None:
        self.timings.append({"scene": self.name, "nodes": self.n, "model": model, "seconds": seconds, **extra})


def run_scene(name, resolutions, strains, limits, cm_settings, repeats, rows, timings, forces=None):
    prev = None  # the resolution below: its reference is carried up where the nonlinear FEM is too dear
    for res_n in resolutions:
        lv = _Level(name, res_n, strains, repeats, rows, timings)
        log(f"{name} n={res_n}: {lv.n} nodes, {len(lv.scene.tets)} tets")
        if lv.n <= limits["lin"]:
            _linear_fem(lv)
        if lv.n <= limits["nl"]:
            _nonlinear_fem(lv)
        elif prev is not None:
            _carried_reference(lv, prev)
        if lv.lins:
            for s in strains:
                lv.add(
                    "linear FEM",
                    s,
                    lv.lins[s],
                    lv.lin_t[s],
                    1,
                    "ok",
                    {"precompute_s": lv.lin.t_assemble + lv.lin.t_factor},
                )
        _chainmail(lv, cm_settings)
        _baselines(lv)
        if lv.n <= limits.get("live", 0):
            _live_models(lv)
        if forces is not None and lv.n <= limits.get("force", 0) and PARETO_STRAIN in lv.lins:
            _forces(lv, forces)
        _mass_spring(lv, limits)
        prev = lv


def _linear_fem(lv: _Level) -> None:
    """Linear FEM at every strain (its assembly and factorisation timed once)."""
    scene = lv.scene
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", LockingWarning)
        lin = lv.lin = LinearFEM(scene.pos, scene.tets, E_STUDY, NU_STUDY, scene.constrained)
    lv.timing("linear FEM (precompute)", lin.t_assemble + lin.t_factor)
    for s in lv.strains:
        lv.lin_t[s], r = median_time(lambda: lin.solve(scene.constrained_disp(s)), lv.repeats)
        lv.lins[s] = r.u
    log(f"  linear FEM: assemble {lin.t_assemble:.2f}s factor {lin.t_factor:.2f}s")


def _nonlinear_fem(lv: _Level) -> None:
    """The neo-Hookean FEM ground truth along the strain path; it is the reference on this mesh."""
    scene, strains = lv.scene, lv.strains
    stamps: dict[float, float] = {}  # strain -> CPU seconds when the path reached it
    t0 = time.thread_time()
    fem = lv.fem = NeoHookeanFEM(scene.pos, scene.tets, E_STUDY, NU_STUDY, scene.constrained)
    res = fem.solve_path(
        scene.constrained_disp(1.0), strains, progress=lambda f: stamps.__setitem__(f, time.thread_time() - t0)
    )
    log(f"  neo-Hookean FEM: {res.status}, {res.info['newton_total']} Newton iterations, {res.info['time']:.1f}s")
    lv.nls = res.u
    for s in strains:
        if s in lv.nls:
            lv.refs[s] = lv.nls[s]
    lv.ref_name = "neo-Hookean FEM (same mesh)"
    lv.timing("neo-Hookean FEM path", res.info["time"], status=res.status)
    for s in strains:
        if s in lv.nls:
            lv.add("neo-Hookean FEM", s, lv.nls[s], stamps.get(s, np.nan), res.newton_iterations.get(s), "converged")
        else:
            lv.add("neo-Hookean FEM", s, None, np.nan, None, res.status)


def _carried_reference(lv: _Level, prev: _Level) -> None:
    """The reference of the resolution below, interpolated here; plus its nonlinear correction on top of
    this mesh's linear FEM where both meshes have one."""
    for s in lv.strains:
        if s not in prev.refs:
            continue
        if s in lv.lins and s in prev.lins:
            corr = prev.scene.interpolate(prev.refs[s] - prev.lins[s], lv.scene.pos)
            lv.refs[s] = lv.lins[s] + corr
            lv.ref_name = f"linear FEM + nonlinear correction from {prev.scene.n_nodes} nodes"
        else:
            lv.refs[s] = prev.scene.interpolate(prev.refs[s], lv.scene.pos)
            lv.ref_name = f"interpolated from {prev.scene.n_nodes}-node reference"


def _chainmail(lv: _Level, cm_settings) -> None:
    """Every ChainMail material at every relaxation count and strain, and the rigid worst case."""
    scene = lv.scene
    cm = ChainMailModel(scene.pos, scene.links, scene.fixed)
    warm = ChainMailParams(0.9, 1.1, 0.1, 1)
    cm.solve(scene.grabbed, scene.grab_disp(0.01), warm)  # compile outside timing
    for label, p in cm_settings.items():
        for k in RELAX:
            params = ChainMailParams(p.alpha_min, p.alpha_max, p.beta, k)
            for s in lv.strains:
                t, (u, info) = median_time(lambda: cm.solve(scene.grabbed, scene.grab_disp(s), params), lv.repeats)
                lv.add(f"ChainMail {label} r{k}", s, u, t, k, "ok", {"moved": info["moved"]})
    # worst case of thesis 6.2 (Fig. 6.4): a rigid object, every element moves in the cascade
    rigid = ChainMailParams(1.0, 1.0, 0.0, 0)
    t, (u, info) = median_time(lambda: cm.solve(scene.grabbed, scene.grab_disp(PARETO_STRAIN), rigid), lv.repeats)
    lv.timing("ChainMail rigid (worst case)", t, moved=info["moved"])
    log(f"  ChainMail: {len(cm_settings) * len(RELAX) * len(lv.strains)} runs")


def _baselines(lv: _Level) -> None:
    for s in lv.strains:
        for label, fn in (
            ("baseline: grabbed patch only", baseline_patch),
            ("baseline: distance blend", baseline_blend),
        ):
            lv.add(label, s, fn(lv.scene, s), 0.0, 0, "ok")


def _live_models(lv: _Level) -> None:
    """The simulator's XPBD and projective bodies, settled at every strain."""
    for label, make in LIVE.items():
        for s in lv.strains:
            u, info = settle(make, lv.scene, s, E_STUDY, NU_STUDY)
            extra = {"frames_to_settle": info["frames"], "grab_force_N": info.get("grab_force_N")}
            lv.add(label, s, u, info["ms_per_frame"] / 1e3, info["frames"], info["status"], extra)
        log(f"  {label}: {[r['iterations'] for r in lv.rows[-len(lv.strains) :]]} frames to settle")


def _forces(lv: _Level, forces: list) -> None:
    """The grab reaction against a reference that does not lock, beside the live models' forces."""
    fs, n = PARETO_STRAIN, lv.n
    t0 = time.perf_counter()
    ref = reference_forces(lv.scene, fs, E_STUDY, NU_STUDY, lv.lin, lv.lins[fs], lv.fem, lv.nls.get(fs))
    live = {
        r["model"]: r["grab_force_N"]
        for r in lv.rows
        if r["scene"] == lv.name and r["nodes"] == n and r["strain"] == fs and r.get("grab_force_N") is not None
    }
    forces.append({"scene": lv.name, "nodes": n, "strain": fs, **ref, "live": live})
    log(f"  forces: reference {ref['reference']:.4g} N ({time.perf_counter() - t0:.1f}s), live {live}")


def _mass_spring(lv: _Level, limits) -> None:
    """Mass-spring to equilibrium (symplectic at every strain, explicit at one) within the budgets, and
    the cost of one step at every size (the frame-rate fit uses it even where equilibrium is not run)."""
    scene, c = lv.scene, lv.scene.constrained
    ms = MassSpring(scene.pos, scene.tets, E_STUDY, fixed=scene.fixed)
    if lv.n <= limits["ms"]:
        for s in lv.strains:
            r = ms.solve(c, scene.constrained_disp(s), scheme="symplectic")
            dts = {"dt": r.dt, "dt_eq22": r.info["dt_eq22"], "dt_bound": r.info["dt_bound"]}
            lv.add(
                "mass-spring symplectic",
                s,
                r.u,
                r.info["t_run"],
                r.steps,
                r.status,
                {"t_step_ms": r.info["t_step"] * 1e3, **dts},
            )
        log(f"  mass-spring symplectic: {[row['status'] for row in lv.rows[-len(lv.strains) :]]}")
    if lv.n <= limits["ms_explicit"]:
        s = PARETO_STRAIN
        r = ms.solve(c, scene.constrained_disp(s), scheme="explicit", max_steps=50_000)
        extra = {"t_step_ms": r.info["t_step"] * 1e3, "dt": r.dt}
        lv.add("mass-spring explicit", s, r.u, r.info["t_run"], r.steps, r.status, extra)
        log(f"  mass-spring explicit: {r.status} after {r.steps} steps")
    lv.timing("mass-spring step", _mass_spring_step(ms, scene, lv.repeats))


def _mass_spring_step(ms: MassSpring, scene, repeats) -> float:
    """Seconds per symplectic step of the free mass-spring mesh (one call compiles, ten are timed)."""
    x = scene.pos.copy()
    v = np.zeros_like(x)
    free = np.ones(scene.n_nodes, np.bool_)
    free[scene.constrained] = False
    noc = np.zeros(0, np.int64)
    no3 = np.zeros((0, 3))

    def steps(k):
        return integrate(
            x, v, ms.links, ms.rest, ms.k, 1.0 / ms.mass, 1.0, free, 1e-9, k, SYMPLECTIC, 0.0, 1e30, noc, no3, no3, 0
        )

    steps(1)
    t, _ = median_time(lambda: steps(10), repeats)
    return t / 10


def stability_sweep(strain=0.1, n=8):
    """Mass-spring time step against stability on a small block: eq. (2.2), the exact linearised
    bound 2/omega_max, and the largest step observed to converge (bisection)."""
    scene = sc.block(n)
    c = scene.constrained
    ms = MassSpring(scene.pos, scene.tets, E_STUDY, fixed=scene.fixed)
    disp = scene.constrained_disp(strain)
    base = ms.solve(c, disp, scheme="symplectic", max_steps=1)
    dt22, bound = base.info["dt_eq22"], base.info["dt_bound"]
    sweep = []
    for scheme in ("symplectic", "explicit"):
        bnd = bound if scheme == "symplectic" else ms.solve(c, disp, scheme="explicit", max_steps=1).info["dt_bound"]
        for f in (0.25, 0.5, 0.9, 1.0, 1.1, 1.5, 2.0, 4.0):
            r = ms.solve(c, disp, scheme=scheme, dt=f * dt22, max_steps=20_000)
            sweep.append(
                {
                    "scheme": scheme,
                    "dt": f * dt22,
                    "dt_over_eq22": f,
                    "status": r.status,
                    "steps": r.steps,
                    "residual": r.residual,
                }
            )
        lo, hi = 0.0, 8.0 * max(dt22, bnd)
        for _ in range(14):
            mid = 0.5 * (lo + hi)
            r = ms.solve(c, disp, scheme=scheme, dt=mid, max_steps=20_000)
            if r.status == "converged":
                lo = mid
            else:
                hi = mid
        sweep.append({"scheme": scheme, "observed_critical_dt": lo, "linear_bound": bnd})
    return {
        "nodes": scene.n_nodes,
        "strain": strain,
        "dt_eq22": dt22,
        "dt_bound_symplectic": bound,
        "omega_max": base.info["omega_max"],
        "gamma": base.info["gamma"],
        "runs": sweep,
    }


def realtime_table(rows, timings):
    """Largest N per model updated at 30 / 60 Hz (power-law fit over the resolutions measured)."""
    out = []
    series = {}
    for r in rows:
        if r["strain"] != PARETO_STRAIN or not np.isfinite(r["time_ms"]):
            continue
        if r["model"].startswith("ChainMail") and not r["model"].endswith(("r0", "r16")):
            continue
        series.setdefault((r["scene"], r["model"]), []).append((r["nodes"], r["time_ms"] / 1e3))
    for t in timings:
        if t["model"] in ("mass-spring step", "ChainMail rigid (worst case)"):
            series.setdefault((t["scene"], t["model"]), []).append((t["nodes"], t["seconds"]))
    for (scene, model), pts in sorted(series.items()):
        ns, ts = zip(*pts)
        out.append(
            {
                "scene": scene,
                "model": model,
                "points": len(pts),
                "n_30hz": realtime_size(ns, ts, 30.0),
                "n_60hz": realtime_size(ns, ts, 60.0),
                "measured_max_nodes": max(ns),
            }
        )
    return out


def run(quick: bool, out_dir, scenes=None) -> dict:

    # the machine is shared and has 2 cores: kernels run on one thread and every time in the
    # study is CPU time of the calling thread, which other processes' load does not inflate
    numba.set_num_threads(1)
    mode = "quick" if quick else "full"
    limits = LIMITS[mode]
    strains = QUICK_STRAINS if quick else STRAINS
    resolutions = sc.QUICK_RESOLUTIONS if quick else sc.RESOLUTIONS
    repeats = 3 if quick else 5
    cm_settings = default_chainmail_settings()
    rows: list[dict] = []
    timings: list[dict] = []
    forces: list[dict] = []
    t0 = time.thread_time()
    w0 = time.perf_counter()
    for name in scenes or list(sc.SCENES):
        run_scene(name, resolutions[name], strains, limits, cm_settings, repeats, rows, timings, forces)
    log("mass-spring stability sweep")
    stability = stability_sweep(n=6 if quick else 8)
    results = {
        "mode": mode,
        "material": {"E": E_STUDY, "nu": NU_STUDY},
        "strains": strains,
        "pareto_strain": PARETO_STRAIN,
        "limits": limits,
        "rows": rows,
        "timings": timings,
        "stability": stability,
        "realtime": realtime_table(rows, timings),
        "forces": forces,
        "chainmail_settings": {k: vars(v) for k, v in cm_settings.items()},
        "elapsed_cpu_s": time.thread_time() - t0,
        "elapsed_wall_s": time.perf_counter() - w0,
        "clock": "CPU time of the calling thread (numba kernels single-threaded)",
    }
    return results

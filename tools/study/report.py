"""Render the study's results: report.md tables, PNG plots (time vs error with the Pareto front per
scene, error vs imposed displacement, mass-spring stability against time step) and results.json.

Also renders the per-system frame-cost table of the built-in packs (`frame_cost_table`), from the
summary dicts that chainsim.game.trainer.headless.run_pack returns.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import tomli_w

from .live_models import LIVE_PARAMS
from .metrics import pareto_front

# thesis Table 6.5: nodes deformed in real time by earlier methods (their own platforms)
THESIS_TABLE_65 = [
    ("Generalised ChainMail (thesis, Java/VRML, AMD K7)", 5600),
    ("Monserrat BEM (SGI R4400)", 150),
    ("Delingette mass-spring (SGI R4400)", 600),
    ("Terzopoulos spline (SGI R4400)", 64),
    ("Nienhuys fast FEM (500 MHz Xeon)", 2000),
]


def _fmt(v, nd=3):
    if v is None:
        return "-"
    if isinstance(v, float):
        if math.isnan(v):
            return "-"
        if math.isinf(v):
            return "inf"
        if v != 0 and (abs(v) >= 1e5 or abs(v) < 1e-3):
            return f"{v:.2e}"
        return f"{v:.{nd}f}"
    return str(v)


def _table(headers, rows):
    out = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    out += ["| " + " | ".join(_fmt(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


#: a model beats the baselines when its RMS error is below this fraction of the better baseline's
BEAT_MARGIN = 0.99


def pareto_rows(results, scene):
    rows = [
        r
        for r in results["rows"]
        if r["scene"] == scene
        and r["strain"] == results["pareto_strain"]
        and r.get("rms_error") is not None
        and np.isfinite(r["time_ms"])
        and r["model"] != "neo-Hookean FEM"
    ]
    base = baselines(results, scene)
    for r in rows:
        b = base.get((r["nodes"], r["strain"]))
        r["vs_baseline"] = r["rms_error"] / b if b else None
        # beating means at least 1 % lower error than the better baseline (equal within noise is not a win)
        r["beats_baselines"] = bool(b) and r["rms_error"] < BEAT_MARGIN * b and not r["model"].startswith("baseline")
    # only a model that beats both baselines can be called Pareto-optimal
    eligible = [i for i, r in enumerate(rows) if r["beats_baselines"]]
    sub = pareto_front([(max(rows[i]["time_ms"], 1e-4), rows[i]["rms_error"]) for i in eligible])
    front = sorted((eligible[j] for j in sub), key=lambda i: rows[i]["time_ms"])
    return rows, front


def model_table(results) -> dict:
    """The rows `model = "auto"` chooses from: each live model's error and cost per update at the
    Pareto strain, per scene and mesh size (TOML-ready)."""
    family = {"ChainMail": "chainmail", "XPBD": "xpbd", "projective": "projective"}
    rows = []
    for r in results["rows"]:
        fam = next((v for k, v in family.items() if r["model"].startswith(k)), None)
        if fam is None or r["strain"] != results["pareto_strain"] or r.get("rms_error") is None:
            continue
        if not np.isfinite(r["time_ms"]) or "rigid" in r["model"]:
            continue
        rows.append(
            {
                "scene": r["scene"],
                "nodes": int(r["nodes"]),
                "model": fam,
                "setting": r["model"],
                "params": row_params(fam, r["model"], results.get("chainmail_settings", {})),
                "rms_error": float(r["rms_error"]),
                "ms_per_update": float(r["time_ms"]),
            }
        )
    return {"strain": results["pareto_strain"], "rows": rows}


def row_params(model: str, setting: str, materials: dict) -> dict:
    """The body settings a row was measured with, so `auto` builds exactly that body: ChainMail's
    material limits and relaxation count, or the live model's settings (tools/study/live_models.LIVE)."""
    if model == "chainmail":
        name, relax = setting.removeprefix("ChainMail ").rsplit(" r", 1)
        m = materials[name]
        return {"alpha_min": m["alpha_min"], "alpha_max": m["alpha_max"], "beta": m["beta"], "relax": int(relax)}
    return dict(LIVE_PARAMS[setting])


def baselines(results, scene) -> dict:
    """(nodes, strain) -> the better (lower) RMS error of the two baselines."""
    out: dict = {}
    for r in results["rows"]:
        if r["scene"] == scene and r["model"].startswith("baseline") and r.get("rms_error") is not None:
            key = (r["nodes"], r["strain"])
            out[key] = min(out.get(key, np.inf), r["rms_error"])
    return out


def plot_pareto(results, out: Path) -> list[str]:

    matplotlib.use("Agg")

    files = []
    for scene in sorted({r["scene"] for r in results["rows"]}):
        rows, front = pareto_rows(results, scene)
        if not rows:
            continue
        fig, ax = plt.subplots(figsize=(8, 5.5))
        fams = sorted({r["model"].split(" r")[0] if r["model"].startswith("ChainMail") else r["model"] for r in rows})
        markers = dict(zip(sorted({r["nodes"] for r in rows}), "os^D"))
        for i, fam in enumerate(fams):
            sel = [
                r
                for r in rows
                if (r["model"].split(" r")[0] if r["model"].startswith("ChainMail") else r["model"]) == fam
            ]
            for r in sel:
                ax.scatter(
                    max(r["time_ms"], 1e-4),
                    r["rms_error"],
                    color=f"C{i}",
                    marker=markers[r["nodes"]],
                    s=40,
                    alpha=0.8,
                    label=fam if r is sel[0] else None,
                )
        fx = [max(rows[i]["time_ms"], 1e-4) for i in front]
        fy = [rows[i]["rms_error"] for i in front]
        ax.step(fx, fy, where="post", color="k", lw=1.2, label="Pareto front")
        ax.axvline(1000 / 30, color="grey", ls="--", lw=0.8)
        ax.axvline(1000 / 60, color="grey", ls=":", lw=0.8)
        ax.text(1000 / 30, max(fy + [0]) * 1.05, " 30 Hz", fontsize=8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("CPU time per update [ms] (mass-spring: to equilibrium; linear FEM: prefactored solve)")
        ax.set_ylabel("RMS displacement error / imposed displacement")
        sizes = ", ".join(f"{m}={n} nodes" for n, m in markers.items())
        ax.set_title(f"{scene}: speed vs accuracy at {results['pareto_strain']:.0%} pull ({sizes})", fontsize=9)
        ax.legend(fontsize=7, loc="best")
        ax.grid(True, which="both", alpha=0.3)
        f = out / f"pareto_{scene}.png"
        fig.tight_layout()
        fig.savefig(f, dpi=110)
        plt.close(fig)
        files.append(f.name)
    return files


def plot_error_vs_strain(results, out: Path) -> list[str]:

    matplotlib.use("Agg")

    scenes = sorted({r["scene"] for r in results["rows"]})
    fig, axes = plt.subplots(1, len(scenes), figsize=(5 * len(scenes), 4.5), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        nodes = min(r["nodes"] for r in results["rows"] if r["scene"] == scene)
        sel = [
            r
            for r in results["rows"]
            if r["scene"] == scene
            and r["nodes"] == nodes
            and r.get("rms_error") is not None
            and r["model"] != "neo-Hookean FEM"
        ]
        models = sorted({r["model"] for r in sel})
        models = [m for m in models if not m.startswith("ChainMail") or m.endswith(("r0", "r16"))]
        for i, m in enumerate(models):
            pts = sorted((r["strain"], r["rms_error"]) for r in sel if r["model"] == m)
            if len(pts) < 2:
                continue
            ax.plot(*zip(*pts), marker="o", ms=3, label=m, color=f"C{i % 10}", ls="-" if i < 10 else "--")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("imposed displacement / length")
        ax.set_ylabel("RMS error / imposed displacement")
        ax.set_title(f"{scene} ({nodes} nodes, vs neo-Hookean FEM)", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    fig.tight_layout()
    f = out / "error_vs_displacement.png"
    fig.savefig(f, dpi=110)
    plt.close(fig)
    return [f.name]


def plot_stability(results, out: Path) -> list[str]:

    matplotlib.use("Agg")

    st = results["stability"]
    fig, ax = plt.subplots(figsize=(7, 4))
    for i, scheme in enumerate(("symplectic", "explicit")):
        runs = [r for r in st["runs"] if r.get("scheme") == scheme and "dt" in r]
        for r in runs:
            ok = r["status"] == "converged"
            ax.scatter(r["dt_over_eq22"], i, marker="o" if ok else "x", s=60, color="C2" if ok else "C3")
        crit = [r for r in st["runs"] if r.get("scheme") == scheme and "observed_critical_dt" in r]
        if crit:
            ax.scatter(crit[0]["observed_critical_dt"] / st["dt_eq22"], i, marker="|", s=400, color="k")
    ax.axvline(1.0, color="C0", ls="--", label="eq. (2.2) critical step")
    ax.axvline(
        st["dt_bound_symplectic"] / st["dt_eq22"],
        color="C1",
        ls=":",
        label="exact linear bound 2/omega_max (symplectic)",
    )
    ax.set_yticks([0, 1], ["symplectic Euler", "explicit Euler"])
    ax.set_xscale("log")
    ticks = [0.25, 0.5, 1, 2, 4]
    ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
    ax.minorticks_off()
    ax.set_xlabel("time step / eq. (2.2) step   (o converged, x diverged, | observed limit)")
    ax.set_title(f"mass-spring stability, block {st['nodes']} nodes, {st['strain']:.0%} pull", fontsize=9)
    ax.legend(fontsize=7)
    ax.set_ylim(-0.7, 1.7)
    fig.tight_layout()
    f = out / "mass_spring_stability.png"
    fig.savefig(f, dpi=110)
    plt.close(fig)
    return [f.name]


def frame_cost_table(summaries: list[dict]) -> str:
    """Markdown table of per-system mean / max frame cost, one block per pack summary.

    Each summary is the dict returned by chainsim.game.trainer.headless.run_pack: {"pack", "scene", "steps",
    "systems": {name: {"mean_ms", "max_ms", ...}}, ...}.
    """
    if not summaries:
        return "_no pack summaries_"
    rows = []
    for s in summaries:
        systems = s.get("systems", {})
        total = sum(v.get("mean_ms", 0.0) for v in systems.values())
        for name, v in sorted(systems.items(), key=lambda kv: -kv[1].get("mean_ms", 0.0)):
            share = v.get("mean_ms", 0.0) / total if total > 0 else 0.0
            rows.append(
                (s.get("pack", "?"), s.get("scene", "-"), name, v.get("mean_ms"), v.get("max_ms"), f"{share:.0%}")
            )
        rows.append((s.get("pack", "?"), s.get("scene", "-"), "**total**", total, None, ""))
    return _table(["pack", "scene", "system", "mean ms", "max ms", "share"], rows)


def forces_section(results) -> list[str]:
    """Markdown lines comparing each live model's settled grab reaction with the force reference."""
    forces = results.get("forces") or []
    if not forces:
        return []
    names = sorted({m for f in forces for m in f["live"]})
    L = [
        f"## Forces: the grab reaction at {results['pareto_strain']:.0%} pull",
        "",
        "The force the grab applies along the pull once the body has settled (`body.grab_force()`), in "
        "newtons, against a reference that does not lock. Linear P1 tetrahedra lock at nu = 0.45, so "
        "the reference is linear elasticity on quadratic (P2, 10-node) tetrahedra of the same mesh times "
        "the neo-Hookean / linear P1 reaction ratio there (the large-strain part): "
        f"*{forces[0]['reference_name']}*. "
        "`/ ref` is a model's force over the reference; `/ P1 NL` is over the neo-Hookean P1 reaction, "
        "the best a model on these linear tetrahedra can reach. ChainMail has no force model "
        "(`grab_force()` is None) and has no row.",
        "",
    ]
    head = ["scene", "nodes", "P2 nodes", "P1 linear", "P1 neo-Hookean", "P2 linear", "reference"]
    for m in names:
        head += [m, "/ ref", "/ P1 NL"]
    rows = []
    for f in forces:
        row = [f["scene"], f["nodes"], f["p2_nodes"], f["p1_linear"], f.get("p1_neohookean"), f["p2_linear"]]
        row.append(f["reference"])
        for m in names:
            v = f["live"].get(m)
            nl = f.get("p1_neohookean")
            row += [v, None if v is None else v / f["reference"], None if v is None or not nl else v / nl]
        rows.append(row)
    L += [_table(head, rows), ""]
    return L


def render_markdown(results, files, pack_section: str) -> str:
    r = results
    L = _intro(r, files)
    for scene in sorted({x["scene"] for x in r["rows"]}):
        L += _pareto_section(r, scene)
    L += forces_section(r)
    L += _fem_section(r)
    L += _stability_section(r["stability"])
    L += _realtime_section(r)
    L += ["", "## Frame cost of the built-in packs by system", "", pack_section, ""]
    return "\n".join(L)


def _intro(r, files) -> list[str]:
    """What was run, how errors and times are measured, and the plots."""
    L = [
        f"# Speed-accuracy study ({r['mode']} run)",
        "",
        f"Material: E = {r['material']['E']:g} Pa, nu = {r['material']['nu']}. Imposed "
        f"displacements (strain = displacement / scene length): {', '.join(f'{s:g}' for s in r['strains'])}.",
        f"Times: {r['clock']}. Study CPU time {r['elapsed_cpu_s']:.0f} s, "
        f"wall {r.get('elapsed_wall_s', float('nan')):.0f} s.",
        "",
        "Errors are RMS (and max) nodal displacement error divided by the imposed displacement, against "
        "the neo-Hookean FEM ground truth; the `reference` column says how the truth was obtained at "
        "each resolution (nonlinear FEM only fits the budget on the coarsest mesh; finer meshes use "
        "linear FEM at that resolution plus the coarse mesh's nonlinear correction, the finest uses the "
        "interpolated reference). Budgets (nodes): " + json.dumps(r["limits"]),
        "",
        "Two baselines set the floor: 'grabbed patch only' (nothing else moves) and 'distance blend' (each "
        "node moves by d_fixed / (d_fixed + d_grab) of the grab, no physics). `err / better baseline` is a "
        "row's error over the better of the two; a row that is not at least 1 % below it is marked NO under "
        "'beats both baselines' and is never on the Pareto front. XPBD and projective rows are the "
        "simulator's own bodies run frame by frame at 60 Hz from rest until they settle: ms/update is CPU "
        "per frame and iters the frames it took.",
        "",
        "Time per update: ChainMail = one cascade from rest plus k relaxation sweeps (`rK`); linear FEM = "
        "the two triangular solves with the factorisation precomputed (precompute time listed apart); "
        "mass-spring = time integrated to static equilibrium (residual 1e-4 of the initial one); "
        "neo-Hookean FEM = Newton path time up to that load.",
        "",
    ]
    for f in files:
        L.append(f"![{f}]({f})")
    L.append("")
    return L


def _pareto_section(r, scene) -> list[str]:
    """One scene's rows at the Pareto strain: who beats the baselines, who is on the front."""
    rows, front = pareto_rows(r, scene)
    L = [f"## {scene}: Pareto table at {r['pareto_strain']:.0%} pull", ""]
    tab = []
    for i, x in sorted(enumerate(rows), key=lambda ix: (ix[1]["nodes"], ix[1]["time_ms"])):
        tab.append(
            (
                x["nodes"],
                x["model"],
                x["time_ms"],
                x["rms_error"],
                x["max_error"],
                x.get("volume_change"),
                x["iterations"],
                x["status"],
                x["vs_baseline"],
                "yes" if x["beats_baselines"] else ("-" if x["model"].startswith("baseline") else "NO"),
                "yes" if i in front else "",
            )
        )
    L.append(
        _table(
            [
                "nodes",
                "model",
                "ms/update",
                "RMS err",
                "max err",
                "dV/V",
                "iters",
                "status",
                "err / better baseline",
                "beats both baselines",
                "Pareto",
            ],
            tab,
        )
    )
    refs = sorted({(x["nodes"], x["reference"]) for x in r["rows"] if x["scene"] == scene}, key=lambda t: t[0])
    L += ["", "References: " + "; ".join(f"{n} nodes: {ref}" for n, ref in refs), ""]
    return L


def _fem_section(r) -> list[str]:
    """Linear against neo-Hookean FEM where both ran, and how the nonlinear solver did."""
    L = ["## FEM agreement (linear vs neo-Hookean, coarsest mesh)", ""]
    tab = [
        (x["scene"], x["nodes"], x["strain"], x["rms_error"], x["max_error"])
        for x in r["rows"]
        if x["model"] == "linear FEM" and x["reference"] and x["reference"].startswith("neo-Hookean")
    ]
    L.append(_table(["scene", "nodes", "strain", "RMS lin-vs-NL", "max lin-vs-NL"], tab))
    L += ["", "Neo-Hookean solver status per scene (load path to 50 %):", ""]
    L.append(
        _table(
            ["scene", "nodes", "status", "CPU s"],
            [
                (t["scene"], t["nodes"], t.get("status"), t["seconds"])
                for t in r["timings"]
                if t["model"] == "neo-Hookean FEM path"
            ],
        )
    )
    return L


def _stability_section(st) -> list[str]:
    """The mass-spring time step: eq. (2.2), the linearised bound and what was observed to converge."""
    L = [
        "",
        "## Mass-spring time step (eq. 2.2)",
        "",
        f"Block {st['nodes']} nodes, {st['strain']:.0%} pull, damping gamma = {st['gamma']:.3g} 1/s. "
        f"eq. (2.2) step (stiffest spring, mean mass): {st['dt_eq22']:.4g} s; exact linearised bound "
        f"2/omega_max: {st['dt_bound_symplectic']:.4g} s.",
        "",
    ]
    crit = [x for x in st["runs"] if "observed_critical_dt" in x]
    L.append(
        _table(
            ["scheme", "observed largest stable dt [s]", "/ eq. (2.2)", "linear bound [s]"],
            [
                (c["scheme"], c["observed_critical_dt"], c["observed_critical_dt"] / st["dt_eq22"], c["linear_bound"])
                for c in crit
            ],
        )
    )
    L += [
        "",
        _table(
            ["scheme", "dt / eq.(2.2)", "status", "steps"],
            [(x["scheme"], x["dt_over_eq22"], x["status"], x["steps"]) for x in st["runs"] if "dt" in x],
        ),
        "",
    ]
    return L


def _realtime_section(r) -> list[str]:
    """The largest mesh each model updates at 30 and 60 Hz, beside the thesis's Table 6.5."""
    L = [
        "## Largest mesh updated at 30 Hz / 60 Hz",
        "",
        "Power-law fit t = a N^b of the per-update CPU time at "
        f"{r['pareto_strain']:.0%} pull over the measured resolutions; values beyond the largest "
        "measured mesh are extrapolations. `mass-spring step` is one integration step (an "
        "interactive simulator takes several per frame, and needs hundreds to settle).",
        "",
    ]

    def shown(v, top):
        # a fit far beyond the measured sizes says only "more than we measured"
        if v is None:
            return None
        return f"> {top} (all measured)" if v > 3 * top else f"{v:.0f}"

    L.append(
        _table(
            ["scene", "model", "points", "largest measured", "N at 30 Hz", "N at 60 Hz"],
            [
                (
                    x["scene"],
                    x["model"],
                    x["points"],
                    x["measured_max_nodes"],
                    shown(x["n_30hz"], x["measured_max_nodes"]),
                    shown(x["n_60hz"], x["measured_max_nodes"]),
                )
                for x in r["realtime"]
            ],
        )
    )
    L += ["", "Thesis Table 6.5 (published figures, other platforms):", ""]
    L.append(_table(["method", "nodes in real time"], THESIS_TABLE_65))
    return L


def write(results: dict, out_dir, pack_summaries=None, pack_note: str = "") -> Path:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = plot_pareto(results, out) + plot_error_vs_strain(results, out) + plot_stability(results, out)
    section = (frame_cost_table(pack_summaries) if pack_summaries else "_not measured_") + (
        "\n\n" + pack_note if pack_note else ""
    )
    results = dict(results, pack_frame_costs=pack_summaries or [], plots=files)
    (out / "results.json").write_text(json.dumps(_finite(results), indent=1, default=_json_default), encoding="utf-8")
    # the table `model = "auto"` reads (ship it as assets/presets/models.toml)
    (out / "models.toml").write_text(
        "# written by `chainsim study speed-accuracy`: error and cost of each model at the Pareto strain\n"
        + tomli_w.dumps(model_table(results)),
        encoding="utf-8",
    )
    md = out / "report.md"
    md.write_text(render_markdown(results, files, section), encoding="utf-8")
    return md


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def _finite(o):
    """Strict JSON: non-finite floats become null."""
    if isinstance(o, dict):
        return {k: _finite(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite(v) for v in o]
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    return o

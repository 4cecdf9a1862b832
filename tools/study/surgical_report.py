"""Writing the surgical-scale study: report.md (tables by material and mesh size), a plot of physical
error against CPU per frame, results.json, and the rows of the model table `auto` reads (merged into an
existing table: the tissue-block rows are replaced, other scenes' rows kept)."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt
import tomli_w

from chainsim.systems.engine.errors import UserError

from .surgical import BLOCK_MM, FRAMES, LIFT_MM, PATCH_MM, model_table


def _f(v, fmt="{:.3f}") -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else fmt.format(v)


def markdown(results: dict, plot: str | None, command: str, machine: str) -> str:
    L = [
        "# Speed and accuracy at surgical scale",
        "",
        f"A {BLOCK_MM[0]:g} x {BLOCK_MM[1]:g} x {BLOCK_MM[2]:g} mm block of tetrahedra, base fixed, a {PATCH_MM:g} x "
        f"{PATCH_MM:g} mm patch of its top lifted {LIFT_MM:g} mm and held for {FRAMES} frames at 60 Hz from rest. "
        "Errors are RMS nodal error / the lift: *solver* against the converged neo-Hookean P1 FEM on the "
        "same mesh, *physical* against the neo-Hookean FEM on the next finer mesh (on the finest solved "
        "mesh, estimated: solver error + a quarter of the coarser mesh's own discretisation error, marked ~). "
        "ms is the median CPU per frame after the first.",
        "",
        f"Made with `{command}` on {machine}.",
        "",
    ]
    if plot:
        L += [f"![physical error against CPU per frame]({plot})", ""]
    rows = results["rows"]
    for mat in dict.fromkeys(r["material"] for r in rows):
        sel = [r for r in rows if r["material"] == mat]
        L += [f"## {mat}: E = {sel[0]['E']:g} Pa, nu = {sel[0]['nu']:g}", ""]
        L += [
            "| element mm | nodes | setting | ms/frame | solver error | physical error | volume change "
            "(FEM) | smallest J | substeps | status |",
            "|---:|---:|---|---:|---:|---:|---:|---:|---:|---|",
        ]
        for r in sel:
            phys = _f(r.get("physical_error"))
            if r.get("physical_estimated"):
                phys = "~" + phys
            L.append(
                f"| {r['element_mm']:g} | {r['nodes']} | {r['setting']} | {_f(r['ms_per_frame'], '{:.2f}')} | "
                f"{_f(r.get('solver_error'))} | {phys} | {_f(r.get('volume_change'), '{:+.4f}')} "
                f"({_f(r.get('reference_volume_change'), '{:+.4f}')}) | {_f(r.get('min_J'), '{:.2f}')} | "
                f"{r.get('substeps', '')} | {r['status']} |"
            )
        L.append("")
    L += ["## Reference solves", "", "| material | nodes | seconds |", "|---|---:|---:|"]
    for ref in results["references"]:
        L.append(f"| {ref['material']} | {ref['nodes']} | {ref['seconds']:.1f} |")
    return "\n".join(L) + "\n"


def plot(results: dict, out: Path) -> str | None:
    matplotlib.use("Agg")
    rows = [r for r in results["rows"] if r.get("physical_error") is not None and math.isfinite(r["ms_per_frame"])]
    if not rows:
        return None
    mats = list(dict.fromkeys(r["material"] for r in rows))
    fig, axes = plt.subplots(1, len(mats), figsize=(5 * len(mats), 4.2), squeeze=False)
    for ax, mat in zip(axes[0], mats):
        for setting in dict.fromkeys(r["setting"] for r in rows):
            sel = sorted(
                (r for r in rows if r["material"] == mat and r["setting"] == setting), key=lambda r: r["nodes"]
            )
            if sel:
                ax.plot([r["ms_per_frame"] for r in sel], [r["physical_error"] for r in sel], "o-", label=setting)
        base = [
            r["physical_error"]
            for r in results["rows"]
            if r["material"] == mat and r["model"] == "baseline" and r.get("physical_error") is not None
        ]
        if base:
            ax.axhline(min(base), color="black", ls="--", lw=1, label="best no-physics baseline")
        ax.axvline(16.7, color="grey", ls=":", lw=1)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("CPU ms per frame (dotted: one 60 Hz frame)")
        ax.set_ylabel("physical error (RMS / lift)")
        ax.set_title(f"{mat}: E = {rows[[r['material'] for r in rows].index(mat)]['E']:g} Pa")
    handles: dict[str, Any] = {}
    for ax in axes[0]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(lab, h)
    axes[0][0].legend(handles.values(), handles.keys(), fontsize=7)
    fig.tight_layout()
    name = "surgical-tradeoff.png"
    fig.savefig(out / name, dpi=110)
    plt.close(fig)
    return name


def write(results: dict, out_dir, command: str, machine: str, table: Path | None = None) -> Path:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    png = plot(results, out)
    (out / "results.json").write_text(json.dumps(results, indent=1, default=str), encoding="utf-8")
    fresh = model_table(results)
    (out / "models.toml").write_text(tomli_w.dumps(fresh), encoding="utf-8")
    if table is not None:
        merge_table(Path(table), fresh["rows"])
    md = out / "report.md"
    md.write_text(markdown(results, png, command, machine), encoding="utf-8")
    return md


def merge_table(path: Path, rows: list[dict]) -> None:
    """Replace the tissue-block rows of the table at `path` (other scenes' rows are kept)."""
    try:
        old = tomllib.loads(path.read_text(encoding="utf-8")) if path.exists() else {}
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
        raise UserError(f"--table {path}: cannot read it as a model table ({e})") from None
    kept = [r for r in old.get("rows", []) if isinstance(r, dict) and r.get("scene") != "tissue-block"]
    head = "# written by `chainsim study speed-accuracy` and `chainsim study surgical`: error and cost per model\n"
    try:
        path.write_text(head + tomli_w.dumps({"strain": old.get("strain", 0.1), "rows": kept + rows}), encoding="utf-8")
    except OSError as e:
        raise UserError(f"--table {path}: cannot write it ({e.strerror})") from None

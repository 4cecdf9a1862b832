"""`chainsim bench needle`: the needle packs' tissue, model by model: frame cost, forces, tenting, punctures.

Each needle pack with tissue ([needle_tissue]) is run headless along its textbook path (the anatomy's
first [paths] entry): the needle is placed at the entry, aimed at the target, advanced at the pack's
insert_speed to `--depth` (default: the path's length less 2 mm, or the tissue's end), held a second and
withdrawn. The same attempt runs once per model the tissue can take, and the report gives, per pack
and model:

- ms per frame (the whole App update, median and p90 over the frames the needle moves or holds): the
  trainer holds 60 frames a second where that fits in 16.7 ms;
- the skin's tent at the skin's puncture (its largest displacement under the tip before it gave, from
  the tissue mesh itself, mm) and the depth of each
  layer's puncture along the needle (mm);
- how each differs from the same attempt with the most accurate setting (`--reference`, default the
  hybrid body iterated to convergence every frame): the tent at puncture and the RMS and worst
  displacement difference of the skin's nodes over the second half of the hold, mm;
- force evaluations per second of the needle's force model (needle_force.axial_force called from
  Python, as a haptic loop would, against a budget of 50 us each: a 1 kHz loop's share).

Results go to OUT/results.json and OUT/results.md, and the first model's force-depth curves to
OUT/force_depth.png.
"""

from __future__ import annotations

import json
import logging
import statistics
import time
import tomllib
from pathlib import Path

import esper
import numpy as np

from chainsim.components.input_events import Widget
from chainsim.components.resources import PendingInput
from chainsim.game.packs.pack import discover
from chainsim.game.trainer.headless import build_app
from chainsim.systems.engine import needle_force
from chainsim.systems.engine.argtypes import count
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.progress import progress
from chainsim.systems.procedures import procedure_of
from chainsim.systems.procedures.procedure import Bench
from chainsim.systems.tissue.deformable import Deformable, use_model

logger = logging.getLogger(__name__)

HELP = "the needle packs' tissue per model: ms per frame, tenting and punctures, difference from the reference"
MODELS = ("hybrid", "chainmail", "projective", "xpbd")
#: the most accurate setting: the hybrid body iterated to convergence every frame
REFERENCE = "hybrid-converged"
REFERENCE_ITERATIONS = 30


def add_arguments(p) -> None:
    p.add_argument("--packs", default="", help="needle packs to run, comma-separated (default: every one with tissue)")
    p.add_argument(
        "--models", default="hybrid,chainmail,projective",
        help=f"models, comma-separated, of {', '.join(MODELS)} (default hybrid,chainmail,projective; xpbd under its "
        "substep rule takes minutes a run)",
    )  # fmt: skip
    p.add_argument(
        "--reference", default=REFERENCE, choices=(*MODELS, REFERENCE),
        help=f"the most accurate setting (default {REFERENCE}: the hybrid body with {REFERENCE_ITERATIONS} "
        "iterations a frame, converged every frame)",
    )  # fmt: skip
    p.add_argument("--hold", type=count(1, 600), default=60, help="frames the needle is held at depth (default 60)")
    p.add_argument("--out", default="runs/bench-needle", help="folder for results.json and results.md")


def needle_packs(names: str) -> list:
    found = [f for f in discover() if f.source == "builtin"]
    chosen = [f for f in found if not names or f.name in names.split(",")]
    out = []
    for f in chosen:
        manifest = tomllib.loads((Path(f.path) / "pack.toml").read_text())
        if manifest.get("needle_tissue", {}).get("bodies"):
            out.append((f.name, Path(f.path), manifest))
    if names and len(out) != len(names.split(",")):
        raise UserError(f"--packs: expected needle packs with tissue, got {names!r}")
    return out


def bench_of(pack: str, manifest: dict) -> Bench:
    """The scripted run a pack's procedure declares for the benchmarks (the needle procedure's insertion)."""
    proc = procedure_of(manifest)
    if proc is None or proc.bench is None:
        raise UserError(f"pack {pack}: its procedure declares no benchmark run (a needle pack with tissue has one)")
    return proc.bench


def run_one(pack: str, root: Path, manifest: dict, model: str, hold: int) -> dict:
    bench = bench_of(pack, manifest)
    events, depth, reached = bench.insertion(root, manifest)
    base = "hybrid" if model == REFERENCE else model
    app = build_app(pack, settings={"model": base}, save="a benchmark saves nothing")
    try:
        if model == REFERENCE:
            with app.active():
                for _, d in esper.get_component(Deformable):
                    d.iterations = REFERENCE_ITERATIONS
                    use_model(d, "hybrid")
        dt = app.time.dt
        withdraw = reached + hold * dt
        speed = float(manifest["entities"]["needle"]["needle"].get("withdraw_speed", 60.0))
        events.append((withdraw, Widget("insert", 0.0)))
        app.resource(PendingInput).extend(events)
        n = int((withdraw + depth / speed + 0.5) / dt)
        frame_ms, skin = [], []
        bodies = bench.bodies(app)
        top = [np.unique(d.body.mesh.triangles) for d in bodies]
        for _ in range(n):
            t0 = time.perf_counter()
            app.update(dt)
            ms = (time.perf_counter() - t0) * 1e3
            t = app.time.sim_time
            if 1.5 <= t <= withdraw:
                frame_ms.append(ms)
            if reached + 0.5 * hold * dt <= t <= withdraw:
                skin.append(np.concatenate([d.body.positions[ids] for d, ids in zip(bodies, top)]))
        rows = bench.trace_rows(app)
        punctures: dict[str, float] = {}
        tent_at_pop, deepest = float("nan"), 0.0
        for r in rows:
            deepest = max(deepest, float(r[6]))  # the skin's largest tent so far
            for e in filter(None, r[5].split(";")):
                if e.startswith("puncture:") and e[9:] not in punctures:
                    punctures[e[9:]] = round(float(r[1]), 3)
                    if e == "puncture:skin":
                        tent_at_pop = deepest
        return {
            "pack": pack,
            "model": model,
            "used": model if model == REFERENCE else bodies[0].body.model_used,
            "frames": len(frame_ms),
            "frame_ms_median": statistics.median(frame_ms),
            "frame_ms_p90": float(np.percentile(frame_ms, 90)),
            "peak_axial_N": max(r[2] for r in rows),
            "skin_tent_at_puncture_mm": tent_at_pop,
            "puncture_depth_mm": punctures,
            "_skin": np.stack(skin) if skin else np.zeros((0, 0, 3)),
            "_curve": [(float(r[0]), float(r[1]), float(r[2]), r[5]) for r in rows],
        }
    finally:
        app.close()


def force_rate(seconds: float = 0.5) -> tuple[float, float]:
    """Evaluations per second of the force model from Python, and microseconds each."""
    L = np.array([2.0, 6.0, 8.0, 20.0])
    c = np.full(4, 0.0106)
    args = (3.0, 0.2, 40.0, True, 0.3, L, c, c * 0.02, c * 1.7, 40.0, 0.5, 0.1)
    needle_force.axial_force(*args)  # compiled (or loaded) before timing
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for _ in range(1000):
            needle_force.axial_force(*args)
        n += 1000
    rate = n / (time.perf_counter() - t0)
    return rate, 1e6 / rate


def compare(results: list[dict], reference: str) -> None:
    """Each run's difference from its pack's reference run (tent at puncture, skin nodes over the hold)."""
    for r in results:
        ref = next((x for x in results if x["pack"] == r["pack"] and x["model"] == reference), None)
        if ref is None:
            continue
        r["tent_difference_mm"] = abs(r["skin_tent_at_puncture_mm"] - ref["skin_tent_at_puncture_mm"])
        a, b = r["_skin"], ref["_skin"]
        k = min(len(a), len(b))
        if k:
            diff = np.linalg.norm(a[:k] - b[:k], axis=2)
            r["skin_rms_difference_mm"] = float(np.sqrt(np.mean(diff**2)))
            r["skin_max_difference_mm"] = float(diff.max())


def plot(results: list[dict], model: str, path: Path) -> None:
    """Axial force against time and tip depth for each pack's run with `model`, pops marked."""
    import matplotlib  # noqa: PLC0415 - only this report draws

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    runs = [r for r in results if r["model"] == model]
    fig, axes = plt.subplots(1, len(runs), figsize=(5.5 * len(runs), 3.8), squeeze=False)
    for ax, r in zip(axes[0], runs):
        t, depth, axial, ev = zip(*r["_curve"])
        d, f = np.array(depth), np.array(axial)
        step = np.r_[0.0, np.diff(d)]
        ax.plot(d[step > 0], f[step > 0], color="tab:blue", label="inserting")
        ax.plot(d[step < 0], f[step < 0], color="tab:orange", label="withdrawing")
        for di, fi, e in zip(d, f, ev):
            for name in (x[9:] for x in e.split(";") if x.startswith("puncture:")):
                ax.annotate(name, (di, fi), textcoords="offset points", xytext=(3, 6), fontsize=8)
                ax.plot([di], [fi], "v", color="tab:red")
        ax.axhline(0, color="0.7", lw=0.8)
        ax.set_xlabel("tip depth from first skin contact (mm)")
        ax.set_ylabel("axial force on the needle (N)")
        ax.set_title(f"{r['pack']}: {r['used']}")
        ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def markdown(results: list[dict], rate: float, us: float) -> str:
    lines = [
        "| pack | model | ms/frame median | p90 | peak axial N | skin tent at puncture mm | vs reference: tent mm |"
        " skin RMS mm | skin max mm | punctures (depth mm) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        pops = ", ".join(f"{k} {v:.1f}" for k, v in r["puncture_depth_mm"].items())
        lines.append(
            f"| {r['pack']} | {r['used']} | {r['frame_ms_median']:.2f} | {r['frame_ms_p90']:.2f} | "
            f"{r['peak_axial_N']:.2f} | {r['skin_tent_at_puncture_mm']:.2f} | {r.get('tent_difference_mm', 0):.2f} | "
            f"{r.get('skin_rms_difference_mm', 0):.3f} | {r.get('skin_max_difference_mm', 0):.3f} | {pops} |"
        )
    lines.append("")
    lines.append(f"Force model: {rate:,.0f} evaluations per second from Python, {us:.2f} us each (budget 50 us).")
    return "\n".join(lines) + "\n"


def run(args) -> int:
    models = [m for m in args.models.split(",") if m]
    bad = [m for m in models if m not in (*MODELS, REFERENCE)]
    if bad:
        raise UserError(f"--models: unknown model {bad[0]!r}; expected some of {', '.join(MODELS)}")
    if args.reference not in models:
        models.append(args.reference)
    packs = needle_packs(args.packs)
    results = []
    for (name, root, manifest), model in progress(
        [(p, m) for p in packs for m in models], desc="needle runs", unit="run"
    ):
        results.append(run_one(name, root, manifest, model, args.hold))
    compare(results, args.reference)
    rate, us = force_rate()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    plot(results, models[0], out / "force_depth.png")
    clean = [{k: v for k, v in r.items() if not k.startswith("_")} for r in results]
    (out / "results.json").write_text(
        json.dumps({"runs": clean, "force_evaluations_per_s": rate, "force_us": us}, indent=2)
    )
    text = markdown(clean, rate, us)
    (out / "results.md").write_text(text)
    print(text, end="")
    print(f"results: {out / 'results.json'}")
    return 0

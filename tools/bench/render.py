"""`chainsim bench render`: off-screen frame time of the renderer for 10k, 100k and 1M triangles.

Each mesh is a wavy triangulated sheet drawn in a window layout (a 3-D viewport at 75 % of the width
and a control panel) at --size (default 1280x800) on the EGL context. Three modes per size:

    static   nothing changes between frames (draw only)
    full     every vertex moves every frame: positions + all normals recomputed and rewritten (the
             normals on the GPU from 50k vertices on a hardware renderer, see --normals); the upload's
             split is reported: float64 -> float32 conversion, CPU normals, buffer writes, GPU pass
             (the time to issue it; its GPU time is part of the frame), bookkeeping (the rest)
    patch    a local patch (--patch, default 1 % of the vertices, around the centre) moves every frame:
             only those positions and the normals around them are rewritten (the ChainMail case)

A frame is timed from the upload to `ctx.finish()`, so GPU work is included. The three modes take
turns frame by frame. Medians (and 90th percentiles) over --frames frames per mode after warm-up. Writes
results.json, results.md and
bench-render.png into --out (default runs/bench-render); progress goes to stderr.
"""

from __future__ import annotations

import json
import logging
import math
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from chainsim.components.input_events import Widget
from chainsim.components.loader import PackResource
from chainsim.components.resources import PendingInput
from chainsim.game.common.outputs import prepare_output_dir
from chainsim.game.render import meshbuf
from chainsim.game.render import render_system as render
from chainsim.game.render.context import egl_context, offscreen_framebuffer, release_framebuffer
from chainsim.game.render.renderer import Frame, MeshDraw, PanelDraw, Renderer, ViewDraw
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script
from chainsim.game.trainer.options import window_size
from chainsim.systems.engine import argtypes, limits
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.meshgen import triangulated_grid
from chainsim.systems.view.cameras import ViewState
from chainsim.systems.view.ui.viewports import OrbitCamera, fraction_rect
from chainsim.systems.view.ui.widgets import WidgetState, place

logger = logging.getLogger(__name__)

HELP = "off-screen frame time of the renderer for 10k / 100k / 1M triangles"

DEFAULT_SIZES = (10_000, 100_000, 1_000_000)
MODES = ("static", "full", "patch")
#: the parts of a full upload the benchmark reports (GpuMesh.timing, the rest is bookkeeping)
SPLIT = ("convert", "normals", "write", "gpu_pass", "bookkeeping")


def add_arguments(p) -> None:
    p.add_argument(
        "--out", default="runs/bench-render", metavar="DIR", help="output folder (default runs/bench-render)"
    )
    p.add_argument("--size", type=window_size, default=(1280, 800), metavar="WxH", help="frame size (default 1280x800)")
    p.add_argument(
        "--triangles",
        type=argtypes.count(2, limits.MAX_BENCH_ELEMENTS),
        nargs="+",
        default=list(DEFAULT_SIZES),
        metavar="N",
        help="approximate triangle counts (default 10000 100000 1000000)",
    )
    p.add_argument(
        "--frames",
        type=argtypes.frames,
        default=30,
        help="timed frames per case (fewer above 500k triangles; default 30)",
    )
    p.add_argument(
        "--warmup",
        type=argtypes.count(0, limits.MAX_FRAMES),
        default=3,
        help="untimed frames first (default 3; with --pack, any number above 0 is one untimed round of its cases)",
    )
    p.add_argument(
        "--patch",
        type=argtypes.real(0.0, 1.0, low_open=True),
        default=0.01,
        help="fraction of vertices moved in 'patch' mode (default 0.01)",
    )
    p.add_argument(
        "--normals",
        choices=("auto", "cpu", "gpu"),
        default="auto",
        help="where full rewrites compute normals: auto (GPU on a hardware renderer, from 50k vertices), "
        "cpu, gpu (default auto)",
    )
    p.add_argument(
        "--pack",
        metavar="PACK",
        help="instead of sheets: frame time of this pack's real window layout after its scene script "
        "(App update + draw + finish), with where the time goes",
    )
    p.add_argument(
        "--at",
        type=argtypes.real(0.0, 3600.0),
        default=1.9,
        metavar="SECONDS",
        help="with --pack: how far the scene script plays before timing (default 1.9 s: in prp the "
        "points are marked and the needle waits at the skin for the dials)",
    )


def sheet(n_triangles: int):
    """A wavy square sheet of about n triangles, 200 mm across; returns (vertices, triangles, side)."""

    side = max(2, int(round(math.sqrt(n_triangles / 2.0))) + 1)
    pos, tris, _ = triangulated_grid(side, side, 200.0 / (side - 1), dim=3)
    pos = np.asarray(pos, np.float64)
    pos[:, :2] -= 100.0
    pos[:, 2] = 6.0 * np.sin(pos[:, 0] / 15.0) * np.cos(pos[:, 1] / 21.0)
    return pos, np.asarray(tris, np.int64), side


def _frame(gm, size):

    w, h = size
    cam = OrbitCamera(target=np.zeros(3), distance=330.0, yaw=25.0, pitch=40.0)
    main = fraction_rect([0.0, 0.0, 0.75, 1.0], w, h)
    panel = fraction_rect([0.75, 0.0, 0.25, 1.0], w, h)
    specs = [
        {"name": f"w{i}", "kind": k, "label": f"widget {i}", "min": 0.0, "max": 1.0, "key": ""}
        for i, k in enumerate(("button", "toggle", "slider", "dial", "light", "text"))
    ]
    values = {"w1": True, "w2": 0.4, "w3": 0.7}
    return Frame(
        size=(w, h),
        views=[ViewDraw("main", "orbit", main, cam, "Scene"), ViewDraw("panel", "panel", panel, None, "Controls")],
        meshes=[MeshDraw(gm, np.eye(4), (0.85, 0.7, 0.6, 1.0))],
        panels=[PanelDraw("panel", panel, "Controls", place(specs, panel), values, set())],
    )


def run(args) -> int:
    if getattr(args, "pack", None):
        return run_pack(args)
    return run_sheets(args)


def _median_ms(fn, frames: int, warmup: int) -> float:

    out = []
    for i in range(warmup + frames):
        t0 = time.perf_counter()
        fn()
        if i >= warmup:
            out.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(out)


#: frames per timed block of a pack bench case, and untimed frames before each block (view images and
#: layers drawn, as in the first frames of a drag)
BLOCK = 8
SETTLE = 3


#: a pack bench case: the set-up to apply, and the change each frame makes (None: none)
Case = tuple[Callable[[], None], Callable[[], None] | None]


def _pack_cases(app, renderer: Renderer, pack) -> dict[str, Case]:
    """Named frame set-ups of the pack bench: a function that switches the speed-ups on or off and
    one that makes a frame's change (None: nothing changes, as between a trainee's actions)."""

    displays = {n: spec.get("display", "") for n, spec in pack.manifest["meshes"].items()}
    orbit = next((v.camera for v in app.resource(ViewState).viewports if v.kind == "orbit"), None)
    dials = [w["name"] for w in app.resource(PackResource).layout.get("widgets", []) if w.get("kind") == "dial"]
    st = app.resource(WidgetState)

    def setup(display=True, culling=True, cache=True, back=True, see=False):
        def apply():
            for n, path in displays.items():
                pack.manifest["meshes"][n]["display"] = path if display else ""
            renderer.cull_enclosed = culling
            renderer.cull_back = back
            renderer.cache_views(cache)
            if "skin_transparent" in st.values and bool(st.values["skin_transparent"]) != see:
                app.resource(PendingInput).push(app.time.sim_time, Widget("skin_transparent", see))
                app.update(app.time.dt)

        return apply

    def turn():
        orbit.yaw = (orbit.yaw + 0.5) % 360.0
        orbit.update_eye()

    def dial():
        name = dials[0]
        v = float(st.values.get(name, 0.0))
        app.resource(PendingInput).push(app.time.sim_time, Widget(name, 1.0 if v <= 0.0 else 0.0))

    before = setup(display=False, culling=False, cache=False, back=False)
    now = setup()
    cases: dict[str, Case] = {
        "before: full meshes, all faces, every view every frame": (before, None),
        "every view drawn every frame (display copies, hidden meshes and faces skipped)": (setup(cache=False), None),
        "  the same with the full meshes": (setup(display=False, cache=False), None),
        "  the same drawing meshes enclosed by the opaque skin": (setup(culling=False, cache=False), None),
        "  the same drawing the back faces of closed meshes": (setup(back=False, cache=False), None),
        "window: nothing changes (views copied from their images)": (now, None),
    }
    if orbit is not None:
        cases["window: orbiting the camera (its view redrawn)"] = (now, turn)
    if dials:
        cases[f"window: turning the {dials[0]} dial (needle over the surgeon's view, tip view redrawn)"] = (now, dial)
    if "skin_transparent" in st.values:
        see = setup(see=True)
        cases["window, skin see-through: nothing changes"] = (see, None)
        if orbit is not None:
            cases["window, skin see-through: orbiting the camera"] = (see, turn)
        if dials:
            cases[f"window, skin see-through: turning the {dials[0]} dial"] = (see, dial)
    return cases


def run_pack(args) -> int:
    """The pack's window layout, drawn off screen at --size after its scene script has played --at seconds:
    median frame time of App.update + draw + finish in the set-ups of `_pack_cases`, which take turns
    frame by frame (a change of machine load hits them alike), and the frame with parts left out."""

    if args.frames < 1 or args.warmup < 0:
        raise UserError("--frames must be >= 1 and --warmup >= 0")
    out = prepare_output_dir(args.out, "--out")
    app = build_app(args.pack, render=True, size=args.size)
    rows = {}
    cpu = {}
    try:
        pres = app.resource(PackResource)
        if pres.scene_spec.get("script"):
            app.resource(PendingInput).extend(load_script(pres.pack.file(pres.scene_spec["script"])))
        app.run_steps(int(args.at / app.time.dt))
        pending = app.resource(PendingInput)
        del pending.items[pending.cursor :]  # the rest of the script would change frames under the timing
        target = app.resource(render.RenderTarget)
        ctx = target.ctx
        renderer: Renderer = app.resource(Renderer)
        target.samples = 1  # as the window under software GL (no multisampling there)
        cases = _pack_cases(app, renderer, pres.pack)
        times: dict[str, list[float]] = {k: [] for k in cases}
        cpu_times: dict[str, list[float]] = {k: [] for k in cases}
        # each case runs as a block of frames, as a drag or an orbit lasts many frames; the blocks take
        # turns, so a change of machine load hits every case alike
        block = min(BLOCK, args.frames)
        warm = 1 if args.warmup else 0  # one untimed round of blocks
        for i in range(warm + -(-args.frames // block)):
            for name, (apply, change) in cases.items():
                apply()
                for j in range(SETTLE + block):  # the set-up's first frames (view images drawn) are not timed
                    c0, t0 = time.process_time(), time.perf_counter()
                    if change is not None:
                        change()
                    app.update(app.time.dt)
                    render.draw(app)
                    ctx.finish()
                    if i >= warm and j >= SETTLE and len(times[name]) < args.frames:
                        times[name].append((time.perf_counter() - t0) * 1e3)
                        cpu_times[name].append((time.process_time() - c0) * 1e3)
        for name in cases:
            rows[name] = statistics.median(times[name])
            cpu[name] = statistics.median(cpu_times[name])
        cases[next(iter(cases))][0]()  # "before" set-up for the parts below: every view drawn
        renderer.cache_views(False)

        def draw_only():
            render.draw(app)
            ctx.finish()

        for samples in sorted({min(4, ctx.max_samples)} - {1}):
            target.samples = samples
            rows[f"draw, MSAA x{samples} (as snapshots)"] = _median_ms(draw_only, args.frames, 1)
        target.samples = 1
        rows["App.update alone (one fixed step)"] = _median_ms(lambda: app.update(app.time.dt), args.frames, 1)
        st = app.resource(WidgetState)
        if "skin_transparent" in st.values:
            had = st.values["skin_transparent"]
            app.resource(PendingInput).push(app.time.sim_time, Widget("skin_transparent", True))
            app.update(app.time.dt)
            rows["every view drawn every frame, skin see-through (sorted see-through pass)"] = _median_ms(
                draw_only, args.frames, 1
            )
            app.resource(PendingInput).push(app.time.sim_time, Widget("skin_transparent", had))
            app.update(app.time.dt)
        real_render = renderer._scene
        renderer._scene = lambda *a, **k: None  # type: ignore[method-assign]  # swapped out for one measurement
        try:
            rows["draw without the 3-D scenes (panels, text, clears)"] = _median_ms(draw_only, args.frames, 1)
        finally:
            renderer._scene = real_render  # type: ignore[method-assign]
        n_tri = sum(int(gm.n_indices) // 3 for gm in renderer.meshes.values())
    finally:
        app.close()
    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    info = {
        "pack": args.pack,
        "size": list(args.size),
        "renderer": ctx.info.get("GL_RENDERER", "?"),
        "cpu_count": os.cpu_count(),
        "load_average_1_5_15": list(load),
        "triangles_uploaded": n_tri,
        "median_ms": rows,
        "median_cpu_ms": cpu,
    }
    (out / "results-pack.json").write_text(json.dumps(info, indent=2), encoding="utf-8")
    print(
        f"# {args.pack} window layout, {args.size[0]}x{args.size[1]}, {info['renderer']}, "
        f"{info['cpu_count']} CPUs, load {load[0]:.1f}"
    )
    print("frame = App.update + draw + finish; CPU = process time of all threads (the rasteriser's too)")
    print("| frame | median (ms) | fps | CPU (ms) |")
    print("|---|---:|---:|---:|")
    for k, v in rows.items():
        c = f"{cpu[k]:.1f}" if k in cpu else ""
        print(f"| {k} | {v:.1f} | {1000.0 / v:.1f} | {c} |")
    return 0


def run_sheets(args) -> int:

    if args.frames < 1 or args.warmup < 0:
        raise UserError("--frames must be >= 1 and --warmup >= 0")
    if not (0.0 < args.patch <= 1.0):
        raise UserError(f"--patch must be a fraction in (0, 1], got {args.patch}")
    if any(n < 2 for n in args.triangles):
        raise UserError("--triangles: each count must be >= 2")
    out = prepare_output_dir(args.out, "--out")
    ctx = egl_context()
    renderer = Renderer(ctx)
    fbo = offscreen_framebuffer(ctx, args.size)
    rows = []
    meshbuf.GPU_NORMALS = getattr(args, "normals", "auto")
    try:
        for n in args.triangles:
            pos, tris, side = sheet(n)
            frames = args.frames if len(tris) <= 500_000 else max(5, args.frames // 3)
            gm = renderer.mesh(("bench", n), pos, tris)
            frame = _frame(gm, args.size)
            lifted = pos.copy()
            lifted[:, 2] += 2.0 * np.cos(pos[:, 0] / 9.0)
            centre = np.argsort(np.linalg.norm(pos[:, :2], axis=1))[: max(1, int(args.patch * len(pos)))]
            patch_ids = np.sort(centre)
            # the modes take turns frame by frame, so a change in machine load hits all three alike
            logger.info(f"  {len(tris):>9,} triangles ({frames} frames per mode) ...")
            times: dict[str, list[float]] = {m: [] for m in MODES}
            uploads: dict[str, list[float]] = {m: [] for m in MODES}
            split: dict[str, list[float]] = {k: [] for k in SPLIT}
            state = [lifted, pos]
            for i in range(args.warmup + frames):
                target = state[i % 2]
                for mode in MODES:
                    t0 = time.perf_counter()
                    if mode == "full":
                        gm.timing = timing = dict[str, float]()  # filled by the upload
                        gm.mark(np.arange(gm.n))
                        gm.upload(target)
                    elif mode == "patch":  # only the patch ids are read from `target`
                        gm.mark(patch_ids)
                        gm.upload(target)
                    t1 = time.perf_counter()
                    renderer.render(frame, fbo)
                    ctx.finish()
                    t2 = time.perf_counter()
                    if i >= args.warmup:
                        times[mode].append((t2 - t0) * 1e3)
                        uploads[mode].append((t1 - t0) * 1e3)
                        if mode == "full":
                            parts = {k: timing.get(k, 0.0) for k in SPLIT if k != "bookkeeping"}
                            parts["bookkeeping"] = (t1 - t0) * 1e3 - sum(parts.values())
                            for k, v in parts.items():
                                split[k].append(v)
                    gm.timing = None
            for mode in MODES:
                rows.append(
                    {
                        "triangles": int(len(tris)),
                        "vertices": int(len(pos)),
                        "mode": mode,
                        "frames": frames,
                        "median_ms": statistics.median(times[mode]),
                        "p90_ms": float(np.percentile(times[mode], 90)),
                        "upload_median_ms": statistics.median(uploads[mode]),
                        "moved_vertices": {"static": 0, "full": int(len(pos)), "patch": int(len(patch_ids))}[mode],
                        "normals_on": "gpu" if mode == "full" and gm.normals_on_gpu else "cpu",
                        "upload_split_ms": {k: statistics.median(v) for k, v in split.items() if mode == "full"},
                    }
                )
                r = rows[-1]
                print(
                    f"    {mode:<6} median {r['median_ms']:.2f} ms (upload {r['upload_median_ms']:.2f} ms)",
                    file=sys.stderr,
                    flush=True,
                )
            renderer.forget(("bench", n))
    finally:
        renderer.release()
        release_framebuffer(ctx, fbo)

    load = os.getloadavg() if hasattr(os, "getloadavg") else (float("nan"),) * 3
    info = {
        "renderer": ctx.info.get("GL_RENDERER", "?"),
        "gl_version": ctx.info.get("GL_VERSION", "?"),
        "cpu_count": os.cpu_count(),
        "load_average_1_5_15": list(load),
        "size": list(args.size),
        "python": platform.python_version(),
        "machine": platform.machine(),
        "patch_fraction": args.patch,
        "rows": rows,
    }
    (out / "results.json").write_text(json.dumps(info, indent=2), encoding="utf-8")
    md = [
        f"# Render benchmark ({args.size[0]}x{args.size[1]}, {info['renderer']})",
        "",
        "Frame time from upload to ctx.finish(); medians over the timed frames. "
        f"{info['cpu_count']} CPUs, load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} at the end "
        "(a software renderer shares those CPUs with everything else running).",
        "",
        "| triangles | mode | moved vertices | frame median (ms) | frame p90 (ms) | upload median (ms) | fps "
        "(median) | normals | upload split (ms): convert / CPU normals / writes / GPU pass / bookkeeping |",
        "|---:|---|---:|---:|---:|---:|---:|---|---|",
    ]
    for r in rows:
        sp = r["upload_split_ms"]
        split_txt = " / ".join(f"{sp[k]:.2f}" for k in SPLIT) if sp else ""
        md.append(
            f"| {r['triangles']:,} | {r['mode']} | {r['moved_vertices']:,} | {r['median_ms']:.2f} | "
            f"{r['p90_ms']:.2f} | "
            f"{r['upload_median_ms']:.2f} | {1000.0 / r['median_ms']:.1f} | "
            f"{r['normals_on'] if r['mode'] != 'static' else ''} | {split_txt} |"
        )
    (out / "results.md").write_text("\n".join(md) + "\n", encoding="utf-8")
    _plot(rows, out / "bench-render.png", info)
    print("\n".join(md))
    print(f"\nwrote {out}/results.json, results.md, bench-render.png")
    return 0


def _plot(rows, path, info) -> None:

    matplotlib.use("Agg")

    sizes = sorted({r["triangles"] for r in rows})
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10, 4.2), dpi=120)
    width = 0.26
    x = np.arange(len(sizes))
    for k, mode in enumerate(MODES):
        for axis, key in ((ax, "median_ms"), (ax2, "upload_median_ms")):
            vals = [next((r[key] for r in rows if r["triangles"] == s and r["mode"] == mode), np.nan) for s in sizes]
            if axis is ax2 and mode == "static":
                continue  # nothing is uploaded
            axis.bar(x + (k - 1) * width, vals, width, label=mode, color=f"C{k}")
    ax.axhline(1000 / 60, color="0.4", lw=0.8, ls="--", label="60 fps")
    for axis, title in ((ax, "frame time (upload + draw + finish)"), (ax2, "upload of moved vertices + normals")):
        axis.set_yscale("log")
        axis.set_xticks(x, [f"{s:,}" for s in sizes])
        axis.set_xlabel("triangles")
        axis.set_ylabel("median (ms)")
        axis.set_title(title, fontsize=9)
        axis.legend(fontsize=8)
    fig.suptitle(f"Off-screen renderer, {info['size'][0]}x{info['size'][1]}, {info['renderer'][:48]}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)

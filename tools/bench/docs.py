"""`chainsim bench docs`: what the in-window pages cost (chainsim.systems.view.ui.markdown laid out and drawn
by chainsim.game.render.docview) - once when a page opens, and every frame while it stays open.

For each page (the key page F1 shows and every docs page of --pack), on the EGL context at --size:

    open     parse + lay out the page's Markdown at the page box's width (the layout cache emptied
             first), then its first draw (which builds the heading fonts' glyph atlases the first time)
    build    per frame: the glyph and shape quads of the open page (PageView.draw, layout cached)
    flush    per frame: uploading and drawing those quads (Overlay.flush) up to `ctx.finish()`
    frame    per frame: the pack's whole window frame (render_system.draw + finish) with the page open,
             minus the same frame with it closed: what an open page adds to a frame

Medians over --frames frames after --warmup. Writes results.json and results.md into --out
(default runs/bench-docs); progress goes to stderr.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time

from chainsim.components.hud import HudState
from chainsim.game.common.outputs import prepare_output_dir
from chainsim.game.render import render_system as render
from chainsim.game.render.renderer import Renderer
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.options import window_size
from chainsim.systems.engine import argtypes, limits
from chainsim.systems.engine.errors import UserError
from chainsim.systems.view.cameras import ViewState, main_view
from chainsim.systems.view.ui import docbox
from chainsim.systems.view.ui import markdown as md

HELP = "cost of the in-window help pages: opening one and keeping it open, per frame"


def add_arguments(p) -> None:
    p.add_argument("--out", default="runs/bench-docs", metavar="DIR", help="output folder (default runs/bench-docs)")
    p.add_argument("--size", type=window_size, default=(1280, 800), metavar="WxH", help="frame size (default 1280x800)")
    p.add_argument("--pack", default="cutting", metavar="PACK", help="pack whose pages and window (default cutting)")
    p.add_argument("--frames", type=argtypes.frames, default=40, help="timed frames per page (default 40)")
    p.add_argument(
        "--warmup", type=argtypes.count(0, limits.MAX_FRAMES), default=3, help="untimed frames first (default 3)"
    )


def _median_ms(xs: list[float]) -> float:
    return round(statistics.median(xs) * 1e3, 3)


def _frame_ms(app, n: int, warmup: int) -> tuple[float, float]:
    """Median wall-clock and CPU (every thread of this process: Mesa's rasteriser threads too) ms of a
    whole frame. The CPU time is the steadier figure on a machine others share."""
    ctx = app.resource(render.RenderTarget).ctx
    wall, cpu = [], []
    for k in range(warmup + n):
        t, c = time.perf_counter(), time.process_time()
        render.draw(app)
        ctx.finish()
        if k >= warmup:
            wall.append(time.perf_counter() - t)
            cpu.append(time.process_time() - c)
    return _median_ms(wall), _median_ms(cpu)


def measure(pack: str, size: tuple[int, int], frames: int, warmup: int) -> dict:
    app = build_app(pack, render=True, size=size)
    try:
        hud: HudState = app.resource(HudState)
        renderer: Renderer = app.resource(Renderer)
        target = app.resource(render.RenderTarget)
        target.samples = 1  # as the window on a software renderer draws (no multisampling)
        ctx = target.ctx
        pages = renderer.pages
        closed = _frame_ms(app, frames, warmup)
        names = ["keys", *app.resource(render.PackResource).pack.section("docs")]
        rows = []
        for name in names:
            hud.open_doc(name)
            with app.active():
                title, text, buttons = render.page(app)
            main = main_view(app.resource(ViewState))
            if main is None:
                raise UserError(f"pack {pack!r} has no view to show its pages in")
            box = docbox.box(main.rect)
            width = docbox.text_area(box).scaled(renderer.overlay.scale).w
            pages._cache.clear()
            t = time.perf_counter()
            lines = md.layout(md.parse(text), width, pages.measure, pages.line_h)
            layout_s = time.perf_counter() - t
            pages._cache.clear()
            t = time.perf_counter()
            pages.draw(box, renderer.overlay.scale, title, text, 0, buttons)  # lays out again, builds fonts
            first_s = time.perf_counter() - t
            renderer.overlay.shapes.clear()
            renderer.overlay.glyphs.clear()
            build, flush, flush_cpu = [], [], []
            quads = 0
            for k in range(warmup + frames):
                t0 = time.perf_counter()
                pages.draw(box, renderer.overlay.scale, title, text, 0, buttons)
                t1, c1 = time.perf_counter(), time.process_time()
                ov = renderer.overlay
                quads = len(ov.shapes) // 36 + sum(len(g) // 48 for g in ov.glyphs.values())
                renderer.overlay.flush(app.resource(render.RenderTarget).size or tuple(size))
                ctx.finish()
                t2, c2 = time.perf_counter(), time.process_time()
                if k >= warmup:
                    build.append(t1 - t0)
                    flush.append(t2 - t1)
                    flush_cpu.append(c2 - c1)
            opened = _frame_ms(app, frames, warmup)
            hud.close_doc()
            rows.append(
                {
                    "page": name,
                    "chars": len(text),
                    "lines": len(lines),
                    "quads": quads,
                    "open_layout_ms": round(layout_s * 1e3, 3),
                    "open_first_draw_ms": round(first_s * 1e3, 3),
                    "build_ms": _median_ms(build),
                    "flush_ms": _median_ms(flush),
                    "flush_cpu_ms": _median_ms(flush_cpu),
                    "frame_open_ms": opened[0],
                    "frame_closed_ms": closed[0],
                    "frame_added_ms": round(opened[0] - closed[0], 3),
                    "frame_open_cpu_ms": opened[1],
                    "frame_closed_cpu_ms": closed[1],
                    "frame_added_cpu_ms": round(opened[1] - closed[1], 3),
                }
            )
            print(f"bench docs: {name}: {rows[-1]}", file=sys.stderr)
        return {
            "pack": pack,
            "size": list(size),
            "frames": frames,
            "gl_renderer": ctx.info.get("GL_RENDERER", ""),
            "cpu": platform.processor() or platform.machine(),
            "cpus": os.cpu_count(),
            "pages": rows,
        }
    finally:
        app.close()


def markdown_table(res: dict) -> str:
    head = (
        "| page | chars | lines | quads | open ms (layout + first draw) | build ms/frame | flush ms/frame "
        "(CPU) | frame open / closed ms (CPU) | added ms/frame (CPU) |\n|---|---|---|---|---|---|---|---|---|\n"
    )
    body = "".join(
        f"| {r['page']} | {r['chars']} | {r['lines']} | {r['quads']} | "
        f"{r['open_layout_ms']:.1f} + {r['open_first_draw_ms']:.1f} | {r['build_ms']:.2f} | "
        f"{r['flush_ms']:.1f} ({r['flush_cpu_ms']:.1f}) | {r['frame_open_ms']:.1f} / {r['frame_closed_ms']:.1f} "
        f"({r['frame_open_cpu_ms']:.1f} / {r['frame_closed_cpu_ms']:.1f}) | "
        f"{r['frame_added_ms']:.1f} ({r['frame_added_cpu_ms']:.1f}) |\n"
        for r in res["pages"]
    )
    return f"{res['pack']} at {res['size'][0]}x{res['size'][1]}, {res['gl_renderer']}\n\n" + head + body


def run(args) -> int:
    out = prepare_output_dir(args.out, "--out")
    res = measure(args.pack, tuple(args.size), args.frames, args.warmup)
    (out / "results.json").write_text(json.dumps(res, indent=2) + "\n")
    (out / "results.md").write_text(markdown_table(res))
    print(markdown_table(res))
    return 0

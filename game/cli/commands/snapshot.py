"""`chainsim snapshot PACK[/SCENE] --out shot.png [--size WxH] [--steps N]`: the whole window layout
(every viewport, the control panel and the HUD) rendered off screen (EGL) to a PNG.

`--scene NAME` (the same as PACK/NAME) also plays the scene's own script when no --input is given,
long enough for it to finish: `chainsim snapshot prp --scene fluoro --out xray.png` shows the correct
attempt's last C-arm image."""

from __future__ import annotations

import sys

from chainsim.components.input_events import Widget
from chainsim.components.resources import PackResource, PendingInput
from chainsim.game.common.outputs import check_output_file
from chainsim.game.render.context import egl_context
from chainsim.game.render.render_system import screenshot
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script
from chainsim.game.trainer.options import window_size
from chainsim.systems.engine import argtypes
from chainsim.systems.engine.errors import UserError

NAME = "snapshot"
HELP = "render a pack's window layout off screen to a PNG"


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP)
    p.add_argument("pack", help="PACK or PACK/SCENE")
    p.add_argument("--out", required=True, metavar="PNG", help="image to write")
    p.add_argument(
        "--size", type=window_size, default=None, metavar="WxH", help="image size (default: the pack's window_size)"
    )
    p.add_argument(
        "--steps",
        type=argtypes.steps,
        default=1,
        help="simulation steps before the picture (default 1: every system, procedures included, has run once)",
    )
    p.add_argument("--input", metavar="SCRIPT", help="input script played during the steps")
    p.add_argument(
        "--scene",
        metavar="NAME",
        help="scene to show (as PACK/NAME); without --input its own script is played to the end",
    )
    p.add_argument("--pack-path", action="append", default=[], metavar="DIR")
    return p


def run(args) -> int:

    if not args.out.lower().endswith(".png"):
        raise UserError(f"--out {args.out}: expected a file name ending in .png")
    check_output_file(args.out, "--out")
    egl_context()  # no EGL: one clear line and exit 2 before any work

    target = args.pack
    if args.scene:
        target = f"{args.pack.rstrip('/')}/{args.scene}"
    # a picture stores no attempt, whatever Save a script presses
    app = build_app(
        target, pack_paths=args.pack_path, render=True, headless=True, size=args.size, save="a snapshot saves nothing"
    )
    try:
        steps = args.steps
        if args.input:
            app.resource(PendingInput).extend(_unsaved(load_script(args.input)))
        elif args.scene:
            pres = app.resource(PackResource)
            if pres.scene_spec.get("script"):
                timed = _unsaved(load_script(pres.pack.file(pres.scene_spec["script"])))
                app.resource(PendingInput).extend(timed)
                last = max((t for t, _ in timed), default=0.0)
                steps = max(steps, int(last / app.time.dt) + 60)  # the last event, then half a second
        for i in range(steps):
            app.update(app.time.dt)
            if steps >= 2000 and sys.stderr.isatty() and (i + 1) % (steps // 20) == 0:
                print(f"\r  step {i + 1}/{steps}", end="", file=sys.stderr, flush=True)
        path = screenshot(app, args.out)
    finally:
        app.close()
    print(f"wrote {path}")
    return 0


def _unsaved(timed: list) -> list:
    """A script's events without its Save presses: the picture shows the scene as the attempt left it,
    with no save message over it (the built-in scripts end with Save)."""
    return [(t, ev) for t, ev in timed if not (isinstance(ev, Widget) and ev.name == "save")]

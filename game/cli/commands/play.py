"""`chainsim play PACK[/SCENE]`: the trainer window. Without a display, exit 2 and point to `run`."""

from __future__ import annotations

import os
import sys
import threading

from chainsim.game.common.outputs import check_output_file
from chainsim.game.packs import pack as packs
from chainsim.game.records import remote
from chainsim.game.trainer.options import add_device_argument, add_mode_arguments, add_records_arguments
from chainsim.game.trainer.window import run_window
from chainsim.systems.engine import argtypes, limits
from chainsim.systems.engine.errors import UserError

NAME = "play"
HELP = "open the simulator window on a pack"


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP)
    p.add_argument("pack", nargs="?", default="prp", help="PACK or PACK/SCENE (default: prp)")
    p.add_argument("--record", metavar="FILE", help="save the session for `chainsim replay`")
    p.add_argument("--input", metavar="SCRIPT", help="play an input script in the window (demonstrations, tests)")
    p.add_argument(
        "--exit-after",
        type=argtypes.real(0.0, limits.MAX_TIME),
        default=None,
        metavar="SECONDS",
        help="close after this much simulated time",
    )
    p.add_argument("--screenshot", metavar="PNG", help="save a screenshot of the window when closing")
    p.add_argument(
        "--frame-times",
        metavar="CSV",
        help="write each frame's time to this file (frame rate as the trainee sees it: "
        "seconds, interval since the previous frame and time in simulation + drawing, in ms)",
    )
    add_mode_arguments(p)
    add_records_arguments(p)
    add_device_argument(p)
    p.add_argument("--pack-path", action="append", default=[], metavar="DIR")
    return p


def has_display() -> bool:
    if sys.platform.startswith("linux"):
        return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return True


def run(args) -> int:
    if not has_display():
        raise UserError(
            f"no display to open a window on (DISPLAY is not set); run without one: "
            f"chainsim run {args.pack} --headless --steps 600 --out DIR"
        )

    packs.resolve(args.pack, args.pack_path)  # unknown pack: clear error before any window opens
    if args.record:  # outputs too: a session must not end in an unwritable path
        check_output_file(args.record, "--record")
    if args.screenshot:
        check_output_file(args.screenshot, "--screenshot")
    if args.frame_times:
        check_output_file(args.frame_times, "--frame-times")
    if args.records:
        remote.server_url(args.records)  # a malformed address is one line now, not a failed save later
        # The queue drains while the window opens; a slow or absent server never delays it.
        threading.Thread(target=remote.sync_quietly, args=(args.records, args.db), daemon=True).start()
    return run_window(args)

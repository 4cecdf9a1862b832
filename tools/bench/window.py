"""`chainsim bench window`: the prp window's frame rate as a trainee meets it - the real window under
Xvfb, driven with xdotool.

`chainsim bench render --pack prp` times the window's frames off screen; this drives the real one
(`chainsim play prp --frame-times`), buffer swaps and event handling included, through the actions
that redraw the most: keeping still, turning the Horizontal dial by dragging it, orbiting the
surgeon's view by dragging in it, the same with the skin see-through (its toggle clicked), then live
fluoroscopy (the Live switch clicked) kept still and with the dial turning. The points are marked
by an input script first, as the dials only turn in the aiming step.

    chainsim bench window [--out DIR] [--seconds 6] [--python PATH]

Needs Xvfb and xdotool (Debian: apt-get install -y xvfb xdotool). Prints a markdown table of each
phase's median frame interval (frames are paced at 60 fps at most) and 90th percentile, writes it
to results.md, and leaves the frame log, the session's recording (`chainsim replay` plays it back),
the window's output and, with ImageMagick, a screenshot of each phase's end in --out. `--python`
runs another installation's chainsim (a before/after comparison).
"""

from __future__ import annotations

import csv
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import tomli_w

from chainsim.game.common.outputs import prepare_output_dir
from chainsim.game.packs.discovery import resolve
from chainsim.game.packs.pack import load
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script
from chainsim.game.trainer.xvfb import start_xvfb
from chainsim.systems.engine import argtypes
from chainsim.systems.engine.errors import UserError
from chainsim.systems.view.cameras import ViewState

HELP = "frame rate of the real prp window under Xvfb, driven with xdotool (dial, orbit, see-through skin, live X-ray)"
W, H = 1280, 800
MARKS_UNTIL = 1.6  # s of the pack's correct script: its three picks on the face


def _widgets() -> dict[str, tuple[int, int]]:
    """Screen centre (x right, y down) of each prp panel widget at the window's size."""
    app = build_app("prp", size=(W, H))
    try:
        vs = app.resource(ViewState)
        placed = [p for ps in vs.panels.values() for p in ps]
        out = {p.spec["name"]: (p.rect.x + p.rect.w / 2, p.rect.y + p.rect.h / 2) for p in placed}
        view = vs.get("surgeon")
        if view is None:
            raise UserError("the prp pack has no 'surgeon' view to drag in")
        surgeon = view.rect
        out["surgeon"] = (surgeon.x + surgeon.w / 2, surgeon.y + surgeon.h * 0.6)
        return {k: (int(x), H - 1 - int(y)) for k, (x, y) in out.items()}
    finally:
        app.close()


def _marks_script(path: Path) -> None:
    """The pack's correct script cut after its picks on the face."""
    pack = load(resolve("prp")[0])
    data = tomllib.loads(pack.file("scripts/correct.toml").read_text(encoding="utf-8"))
    data["event"] = [e for e in data["event"] if float(e["t"]) <= MARKS_UNTIL]
    data["description"] = "the three marked points of the correct attempt"
    path.write_text(tomli_w.dumps(data), encoding="utf-8")
    load_script(path)  # the cut-down script must still read


def add_arguments(p) -> None:
    p.add_argument(
        "--out", default="runs/bench-window", metavar="DIR", help="output folder (default runs/bench-window)"
    )
    p.add_argument(
        "--seconds",
        type=argtypes.real(1.0, 600.0),
        default=6.0,
        help="length of each moving phase in seconds (default 6)",
    )
    p.add_argument(
        "--python",
        default=None,
        metavar="PATH",
        help="the Python of another installation whose chainsim window to measure (default: this one)",
    )


def run(args) -> int:
    for tool in ("Xvfb", "xdotool"):
        if shutil.which(tool) is None:
            raise UserError(f"bench window needs {tool} (Debian: apt-get install -y xvfb xdotool); it is not installed")
    if args.python is not None and not Path(args.python).is_file():
        raise UserError(f"--python {args.python}: no such file (expected a Python interpreter)")
    out = prepare_output_dir(args.out, "--out")
    chainsim = [args.python or sys.executable, "-m", "chainsim.game.cli.main"]
    widgets = _widgets()
    script = out / "marks.toml"
    _marks_script(script)
    xvfb, display = start_xvfb(W, H)
    env = {**os.environ, "DISPLAY": display}
    env.pop("PYGLET_HEADLESS", None)
    frames = out / "frames.csv"
    records = tempfile.TemporaryDirectory()  # the attempt is not kept
    db = Path(records.name) / "records.sqlite3"
    play = None
    try:
        time.sleep(1.5)
        with open(out / "play.log", "w", encoding="utf-8") as log:
            play = subprocess.Popen(
                [*chainsim, "play", "prp", "--class", "bench", "--trainee", "bench", "--db", str(db)]
                + ["--input", str(script), "--frame-times", str(frames), "--record", str(out / "session.json")],
                env=env,
                stdout=log,
                stderr=subprocess.STDOUT,
            )
        while not (frames.exists() and frames.stat().st_size > 40):
            if play.poll() is not None:
                print((out / "play.log").read_text(encoding="utf-8"), file=sys.stderr)
                return 1
            time.sleep(0.1)
        t0 = time.monotonic()  # about the first frame's time (the log's zero)

        def xdo(*a) -> None:
            subprocess.run(["xdotool", *map(str, a)], env=env, check=False)

        def still(seconds: float) -> None:
            time.sleep(seconds)

        def drag(at: tuple[int, int], step: int):
            def run(seconds: float) -> None:
                xdo("mousemove", *at)
                xdo("mousedown", 1)
                end, k = time.monotonic() + seconds, 0
                while time.monotonic() < end:  # to and fro, 20 moves each way
                    k += 1
                    xdo("mousemove_relative", "--", step if (k // 20) % 2 == 0 else -step, 0)
                    time.sleep(0.01)
                xdo("mouseup", 1)

            return run

        phases = []

        def phase(name: str, action, seconds: float) -> None:
            a = time.monotonic() - t0
            action(seconds)
            phases.append((name, a, time.monotonic() - t0))
            if shutil.which("import"):  # ImageMagick, where installed: what the phase ended on
                shot = out / f"{name.replace(' ', '-')}.png"
                subprocess.run(["import", "-window", "root", str(shot)], env=env, check=False)

        time.sleep(MARKS_UNTIL + 1.5)
        dial, view = drag(widgets["rotate_horizontal"], 2), drag(widgets["surgeon"], 3)
        phase("still", still, 3.0)
        phase("turning a dial", dial, args.seconds)
        phase("orbiting", view, args.seconds)
        xdo("mousemove", *widgets["skin_transparent"])
        xdo("click", 1)
        time.sleep(0.5)
        phase("see-through still", still, 3.0)
        phase("see-through orbiting", view, args.seconds)
        phase("see-through turning a dial", dial, args.seconds)
        # live fluoroscopy (the panel's Live switch, as the pedal held): a new X-ray image 15 times a
        # second of simulated time while the trainee turns the dial under it
        xdo("mousemove", *widgets["fluoro_live"])
        xdo("click", 1)
        time.sleep(0.5)
        phase("live fluoroscopy", still, 3.0)
        phase("live fluoroscopy turning a dial", dial, args.seconds)
        xdo("mousemove", *widgets["fluoro_live"])
        xdo("click", 1)
        # quit as a trainee does: Esc, and Esc again to leave the attempt unsaved (the recording is
        # written on the way out)
        found = subprocess.run(
            ["xdotool", "search", "--name", "chainsim - prp"], env=env, capture_output=True, text=True
        ).stdout.split()
        for _ in range(2):
            if found and play.poll() is None:
                xdo("key", "--window", found[-1], "Escape")
                time.sleep(0.8)
        play.wait(20)
    finally:
        if play is not None and play.poll() is None:
            play.terminate()
            play.wait(10)
        xvfb.terminate()
        xvfb.wait(10)
        records.cleanup()
    with open(frames, encoding="utf-8") as f:
        rows = [(float(r["t_s"]), float(r["interval_ms"])) for r in csv.DictReader(f)]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        f"# the prp window under Xvfb, {W}x{H}, {os.cpu_count()} CPUs, load {load:.1f}",
        "| phase | frames | interval, median (ms) | fps | p90 (ms) |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, a, b in phases:
        iv = sorted(v for t, v in rows if a + 0.7 <= t <= b - 0.2)  # the phase's settled middle
        if not iv:
            continue
        med = statistics.median(iv)
        lines.append(f"| {name} | {len(iv)} | {med:.1f} | {1000.0 / med:.1f} | {iv[int(0.9 * (len(iv) - 1))]:.1f} |")
    (out / "results.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))
    return 0

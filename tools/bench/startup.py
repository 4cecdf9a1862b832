"""`chainsim bench startup`: how long a trainee waits when the window opens, cold and warm.

Each start is a fresh process, `chainsim play PACK` in the real window under Xvfb, timed from the
moment it is started to the lines the window prints (chainsim.game.trainer.window): `window: first
picture` (the first frame drawn), `kernels: the scene's ready` (the scene takes input: the kernels it
needs are there) and `kernels: all compiled` (every kernel a built-in pack can reach). **Cold**: numba's
cache and chainsim's mesh cache empty (a fresh NUMBA_CACHE_DIR and CHAINSIM_CACHE_DIR), as on a new
install before `chainsim warmup`; **warm**: the same caches right after, as every later start.
Python's own bytecode is compiled in both (a first import after install adds a few seconds once).
The machine's load average is reported with the figures, since on a shared 2-core machine it moves
them more than anything in the code.

    chainsim bench startup [--pack prp] [--runs 1] [--json] [--timeout 900]

Needs Xvfb (Debian: apt-get install -y xvfb). `--json` prints one object:
`{"cold": {"first_picture_s", "input_s", "all_compiled_s"}, "warm": {...}, "load": [1, 5, 15 min],
"cpus": N, "pack": NAME, "runs": N}` (medians over the runs).
"""

from __future__ import annotations

import json
import os
import queue
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from chainsim.systems.engine import argtypes
from chainsim.systems.engine.errors import UserError

HELP = "seconds from starting the window to its first picture, the scene taking input and every kernel compiled"
#: the window's lines and the figure each one times
MARKS = {
    "window: first picture": "first_picture_s",
    "kernels: the scene's ready": "input_s",
    "kernels: all compiled": "all_compiled_s",
}
W, H = 1280, 800


def add_arguments(p) -> None:
    p.add_argument("--pack", default="prp", help="the pack to open (default prp)")
    p.add_argument("--runs", type=argtypes.count(1, 20), default=1, help="starts of each kind; medians (default 1)")
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    p.add_argument(
        "--timeout",
        type=argtypes.real(10.0, 3600.0),
        default=900.0,
        help="seconds a start may take before it is called failed (default 900)",
    )


def _reader(stream, lines: queue.Queue) -> None:
    for line in stream:
        lines.put((time.monotonic(), line.rstrip("\n")))
    lines.put((time.monotonic(), None))


def one_start(cmd: list[str], env: dict, timeout: float) -> dict[str, float]:
    """Start `cmd` and time each of MARKS's lines from the start; the process is ended once all came."""
    got: dict[str, float] = {}
    lines: queue.Queue = queue.Queue()
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    threading.Thread(target=_reader, args=(proc.stdout, lines), daemon=True).start()
    said: list[str] = []
    try:
        while len(got) < len(MARKS):
            left = t0 + timeout - time.monotonic()
            if left <= 0:
                raise UserError(f"bench startup: the window gave {sorted(got) or 'nothing'} in {timeout:.0f} s")
            try:
                t, line = lines.get(timeout=left)
            except queue.Empty:
                continue
            if line is None:
                raise UserError("bench startup: the window ended before it was ready: " + " / ".join(said[-5:]))
            said.append(line)
            for mark, key in MARKS.items():
                if line.startswith(mark) and key not in got:
                    got[key] = round(t - t0, 2)
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
    return got


def run(args) -> int:
    if shutil.which("Xvfb") is None:
        raise UserError("bench startup needs Xvfb (Debian: apt-get install -y xvfb); it is not installed")
    display = f":{120 + os.getpid() % 50}"
    xvfb = subprocess.Popen(
        ["Xvfb", display, "-screen", "0", f"{W}x{H}x24", "-nolisten", "tcp"], stderr=subprocess.DEVNULL
    )
    load = [round(x, 2) for x in os.getloadavg()]
    runs: dict[str, list[dict]] = {"cold": [], "warm": []}
    try:
        time.sleep(1.5)
        with tempfile.TemporaryDirectory() as tmp:
            cmd = [sys.executable, "-m", "chainsim.game.cli.main", "play", args.pack, "--class", "bench"]
            cmd += ["--trainee", "bench", "--db", str(Path(tmp) / "records.sqlite3")]
            for k in range(args.runs):
                cache = Path(tmp) / f"numba-cache-{k}"  # empty: cold
                env = {**os.environ, "DISPLAY": display, "NUMBA_CACHE_DIR": str(cache)}
                env["CHAINSIM_CACHE_DIR"] = str(Path(tmp) / f"chainsim-cache-{k}")  # the meshes read, as new
                env.pop("PYGLET_HEADLESS", None)
                for kind in ("cold", "warm"):
                    got = one_start(cmd, env, args.timeout)
                    runs[kind].append(got)
                    if not args.json:
                        print(f"{kind} start {k + 1}: " + ", ".join(f"{key} {v:.1f}" for key, v in got.items()))
    finally:
        xvfb.terminate()
    out = {kind: {key: statistics.median(r[key] for r in rs) for key in MARKS.values()} for kind, rs in runs.items()}
    result = {**out, "load": load, "cpus": os.cpu_count(), "pack": args.pack, "runs": args.runs}
    if args.json:
        print(json.dumps(result))
    else:
        print(f"{args.pack}, {os.cpu_count()} CPUs, load {load[0]:.1f} {load[1]:.1f} {load[2]:.1f} before the starts")
        print("| start | first picture s | scene takes input s | every kernel compiled s |")
        print("|---|---|---|---|")
        for kind, v in out.items():
            print(f"| {kind} | {v['first_picture_s']:.1f} | {v['input_s']:.1f} | {v['all_compiled_s']:.1f} |")
    return 0

"""`chainsim bench train`: the trainer in browser tabs, measured as trainees would see it.

Starts ``chainsim serve`` on a throwaway SQLite database with one trainee account per tab, opens the
tabs in headless Chromium (the distribution's /usr/bin/chromium, driven by Playwright) on
``/train/PACK``, and for 1, 2, ... N tabs at once turns the Horizontal turn dial back and forth in
every tab (the needle moves: every frame changes, the stream's worst steady case) while pressing F5
and F6 (Front and Side views) once a second. Each tab counts the frames it drew and the bytes it
received, and times each key press from sending it to drawing the first picture that shows it
(``window.trainStats`` of static/train.js): frames per second, input-to-picture latency (median, 90th
and 95th percentiles) and bandwidth per session, how long a new tab waited for its first picture, and
so how many sessions hold 20 frames per second. ``--rtt-ms`` puts a relay that delays every byte by
half that round trip each way between the tabs and the server (``delay_proxy``), as a long network
does; without it the tabs talk to the server over loopback.
Before the tabs it encodes one frame of the pack as JPEG and WebP at the stream's quality, timing
each and weighing the result, which is why the stream is JPEG (docs/records-server.md).
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

from chainsim.systems.engine.errors import UserError

HELP = "the trainer in browser tabs: fps, input-to-picture latency, bandwidth per session, sessions at 20 fps"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
PASSWORD = "bench password 1"
HOLD_FPS = 20.0

# the Horizontal turn dial's knob in the prp trainer's default 1280 x 800 window (from the top-left)
DIAL = (898, 364)
DRIVE = """([x, y]) => {
  const c = document.getElementById('train-screen');
  const r = c.getBoundingClientRect();
  const k = r.width / c.width, cx = r.left + x * k, cy = r.top + y * k;
  const fire = (type, init) => c.dispatchEvent(new (type.startsWith('key') ? KeyboardEvent : MouseEvent)(
      type, Object.assign({bubbles: true}, init)));
  fire('keydown', {key: 'Escape', code: 'Escape'}); fire('keyup', {key: 'Escape', code: 'Escape'});
  let a = 0, step = 5, n = 0;
  fire('mousedown', {clientX: cx, clientY: cy, button: 0, buttons: 1});
  window.__drive = setInterval(() => {
    // back and forth at a steady 5 px a tick (a sine's slow turns would leave some pictures unchanged)
    if (Math.abs(a + step) > 70) step = -step;
    a += step;
    const at = {bubbles: true, clientX: cx + a, clientY: cy, buttons: 1};
    c.dispatchEvent(new MouseEvent('mousemove', at));
  }, 16);
  window.__probe = setInterval(() => {
    const key = (n++ % 2) ? 'F6' : 'F5';
    fire('keydown', {key, code: key}); fire('keyup', {key, code: key});
  }, 1000);
}"""
READ = "() => { const s = window.trainStats; return {frames: s.frames, bytes: s.bytes, lat: s.latencies.slice()}; }"


def add_arguments(p) -> None:
    p.add_argument("--sessions", type=int, default=3, help="most tabs at once (measured 1, 2, ... up to this)")
    p.add_argument("--seconds", type=float, default=15.0, help="seconds measured at each number of tabs")
    p.add_argument("--pack", default="prp", help="the pack trained (default prp; the dial turned is where prp's is)")
    p.add_argument("--format", choices=("jpeg", "webp"), default="jpeg", help="the stream's picture format")
    p.add_argument("--quality", type=int, default=70, help="the pictures' quality, 1-100 (default 70)")
    p.add_argument("--rtt-ms", type=float, default=0.0, help="emulated network round trip, ms (default 0: loopback)")
    p.add_argument("--json", default=None, help="also write the figures to this JSON file")


def _free_port() -> int:
    import socket  # noqa: PLC0415

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def encoding_costs(pack: str, quality: int) -> dict:
    """One frame of the pack's trainer, encoded as JPEG and as WebP: milliseconds and kilobytes each."""
    import numpy as np  # noqa: PLC0415

    import chainsim.game.render.render_system as render  # noqa: PLC0415
    from chainsim.game.server.frame_tiles import encode_rgb  # noqa: PLC0415
    from chainsim.game.trainer.headless import build_app  # noqa: PLC0415

    app = build_app(pack, render=True, save="a benchmark saves nothing")
    try:
        render.draw(app)
        target = app.resource(render.RenderTarget)
        w, h = target.fbo.size
        # the whole picture, rows top first, as the session's first frame sends it
        picture = np.frombuffer(target.fbo.read(components=3, alignment=1), np.uint8).reshape(h, w, 3)[::-1]
    finally:
        app.close()
    out = {}
    for fmt in ("jpeg", "webp"):
        times = []
        for _ in range(7):
            t = time.perf_counter()
            data = encode_rgb(picture, fmt, quality)
            times.append(time.perf_counter() - t)
        out[fmt] = {"ms": 1e3 * statistics.median(times), "kb": len(data) / 1024}
    return out


def sessions_cpu_s(server_pid: int) -> float:
    """CPU seconds used so far by the server's session processes (Linux /proc; 0 elsewhere)."""
    total = 0.0
    try:
        tasks = os.listdir(f"/proc/{server_pid}/task")
    except OSError:
        return 0.0
    tick = os.sysconf("SC_CLK_TCK")
    for tid in tasks:
        try:
            children = Path(f"/proc/{server_pid}/task/{tid}/children").read_text().split()
        except OSError:
            continue
        for pid in children:
            try:
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
                if b"train_session" not in cmd:
                    continue
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
                total += (int(fields[11]) + int(fields[12])) / tick
            except (OSError, IndexError, ValueError):
                continue
    return total


def _wait(url: str, proc, log: Path) -> None:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise UserError(f"chainsim serve exited: {log.read_text()[-500:]}")
        try:
            with urllib.request.urlopen(url + "/api/health", timeout=2):
                return
        except OSError:
            time.sleep(0.2)
    raise UserError("chainsim serve did not answer in 60 s")


def _check_args(args) -> None:
    """Each flag in its range, one line naming the flag otherwise."""
    if not 1 <= args.sessions <= 32:
        raise UserError(f"--sessions must be from 1 to 32, got {args.sessions}")
    if not 2.0 <= args.seconds <= 600.0:
        raise UserError(f"--seconds must be from 2 to 600, got {args.seconds:g}")
    if not 1 <= args.quality <= 100:
        raise UserError(f"--quality must be from 1 to 100, got {args.quality}")
    if not 0.0 <= args.rtt_ms <= 2000.0:
        raise UserError(f"--rtt-ms must be from 0 to 2000, got {args.rtt_ms:g}")


def run(args) -> int:
    _check_args(args)
    if args.json:
        from chainsim.game.common.outputs import check_output_file  # noqa: PLC0415

        check_output_file(args.json, "--json")  # before minutes of measuring
    if not os.path.exists(CHROMIUM):
        raise UserError(f"bench train needs Chromium at {CHROMIUM} (apt-get install chromium)")
    try:
        from playwright.sync_api import sync_playwright  # noqa: PLC0415
    except ImportError:
        raise UserError("bench train needs playwright (pip install -e '.[test]')") from None
    from chainsim.game.records import accounts  # noqa: PLC0415
    from chainsim.game.records.store import RecordStore  # noqa: PLC0415

    print(f"load before: {os.getloadavg()[0]:.2f} (1 min), {os.cpu_count()} CPUs", flush=True)
    costs = encoding_costs(args.pack, args.quality)
    for fmt, c in costs.items():
        print(
            f"one {args.pack} frame as {fmt} q{args.quality}: {c['ms']:.1f} ms to encode, {c['kb']:.0f} KiB", flush=True
        )
    folder = Path(tempfile.mkdtemp(prefix="chainsim-bench-train-"))
    db = str(folder / "bench.sqlite3")
    names = [f"t{i + 1}" for i in range(args.sessions)]
    with RecordStore(db) as store:
        for name in names:
            accounts.add_user(store, name, "trainee", PASSWORD, ["bench"])
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    log = folder / "serve.log"
    env = dict(
        os.environ,
        CHAINSIM_TRAIN_SEATS=str(args.sessions),
        CHAINSIM_TRAIN_FORMAT=args.format,
        CHAINSIM_TRAIN_QUALITY=str(args.quality),
    )
    with log.open("wb") as fh:
        server = subprocess.Popen(
            [sys.executable, "-m", "chainsim.game", "serve", "--db", db, "--port", str(port), "--scorers", "1"],
            stdout=fh,
            stderr=subprocess.STDOUT,
            env=env,
        )
    rows, relay = [], None
    try:
        _wait(url, server, log)
        if args.rtt_ms > 0:
            from chainsim.tools.bench.delay_proxy import DelayProxy  # noqa: PLC0415

            relay = DelayProxy(port, args.rtt_ms)
            print(f"the tabs reach the server through a relay adding {args.rtt_ms:g} ms of round trip", flush=True)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS, headless=True)
            try:
                rows = _measure(
                    browser, url if relay is None else f"http://127.0.0.1:{relay.port}", names, args, server.pid
                )
            finally:
                browser.close()
    finally:
        if relay is not None:
            relay.close()
        server.terminate()
        try:
            server.wait(15)
        except subprocess.TimeoutExpired:
            server.kill()
        shutil.rmtree(folder, ignore_errors=True)
    held = max((r["sessions"] for r in rows if r["fps_min"] >= HOLD_FPS), default=0)
    print(f"sessions holding {HOLD_FPS:g} fps: {held}  (load after: {os.getloadavg()[0]:.2f})")
    if args.json:
        Path(args.json).write_text(
            json.dumps(
                {"encoding": costs, "rows": rows, "hold_20fps": held, "format": args.format, "rtt_ms": args.rtt_ms},
                indent=1,
            )
        )
    return 0


def _measure(browser, url: str, names: list[str], args, server_pid: int) -> list[dict]:
    contexts, pages, rows = [], [], []
    print(
        "sessions  fps (min / median)  latency ms (median / p90 / p95)  KiB/s per session  CPU per session  "
        "first picture s  load"
    )
    for k, name in enumerate(names, start=1):
        context = browser.new_context(viewport={"width": 1400, "height": 1000}, bypass_csp=True)
        page = context.new_page()
        page.goto(url + "/login")
        page.fill("input[name=name]", name)
        page.fill("input[name=password]", PASSWORD)
        page.click("button[type=submit]")
        page.wait_for_url("**/trainees/**")
        opened = time.perf_counter()
        page.goto(f"{url}/train/{args.pack}")
        page.wait_for_function("window.trainStats && window.trainStats.frames > 0", timeout=180_000)
        first_picture = time.perf_counter() - opened
        page.evaluate(DRIVE, list(DIAL))
        contexts.append(context)
        pages.append(page)
        time.sleep(2.0)  # every tab turning its dial before the count starts
        start = [pg.evaluate(READ) for pg in pages]
        cpu0, t0 = sessions_cpu_s(server_pid), time.perf_counter()
        time.sleep(args.seconds)
        end = [pg.evaluate(READ) for pg in pages]
        span = time.perf_counter() - t0
        cpu = (sessions_cpu_s(server_pid) - cpu0) / span / k
        fps = [(e["frames"] - s["frames"]) / span for s, e in zip(start, end)]
        kbs = [(e["bytes"] - s["bytes"]) / span / 1024 for s, e in zip(start, end)]
        lat = sorted(x for s, e in zip(start, end) for x in e["lat"][len(s["lat"]) :])
        row = {
            "sessions": k,
            "fps_min": min(fps),
            "fps_median": statistics.median(fps),
            "latency_ms_median": statistics.median(lat) if lat else None,
            "latency_ms_p90": lat[int(0.9 * (len(lat) - 1))] if lat else None,
            "latency_ms_p95": lat[int(0.95 * (len(lat) - 1))] if lat else None,
            "first_picture_s": first_picture,
            "kib_s_median": statistics.median(kbs),
            "cpu_per_session": cpu,
            "load": os.getloadavg()[0],
        }
        rows.append(row)
        latency = (
            f"{row['latency_ms_median']:.0f} / {row['latency_ms_p90']:.0f} / {row['latency_ms_p95']:.0f}"
            if lat
            else "- (no key press shown)"
        )
        print(
            f"{k:8d}  {row['fps_min']:5.1f} / {row['fps_median']:5.1f}       {latency:>30}  "
            f"{row['kib_s_median']:17.0f}  {cpu:14.0%}  {first_picture:15.1f}  {row['load']:.2f}",
            flush=True,
        )
    for context in contexts:
        context.close()
    return rows

"""`chainsim bench haptics`: the 1 kHz servo loop beside a running 60 Hz scene with tissue, measured.

A needle pack with tissue (default prp) runs as the window runs it, paced by the wall clock at 60
frames a second in whole fixed steps (chainsim.game.trainer.frameloop.FixedStepper), nothing drawn: the
needle is placed at the textbook path's entry and aimed at its target by the same events as `bench
needle`, and the simulated device (chainsim.systems.engine.haptics.simdevice) drives the depth: a
hand pushing in at `--speed` mm/s to the path's depth less 2 mm, holding a second and withdrawing. The
servo (`--servo kernel`, the nogil kernel on its own thread; `python`, a Python thread ticking a kernel,
to compare) runs beside it at 1 kHz. Reported:

- the tick period (ms between tick starts: median, p99, p99.9, worst), deadlines missed, ticks later than
  2 ms, and the scheduling the servo thread got;
- the scene's frames a second and ms per simulation step (median, p90; a frame runs the steps its wall time
  holds, at most 12, as the window does);
- the force error of the local model: at each step where the simulation took the servo's depth, the
  servo's force at that tick against the simulation's axial force for that depth (N: median, p99, worst);
- the load average before and after (the machine is shared: figures are quoted with it).

`--json` prints them as one JSON object. Targets: p99 <= 1.2 ms and no tick later than 2 ms.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

from chainsim.components.input_events import Widget
from chainsim.components.resources import PendingInput
from chainsim.game.trainer import plugins
from chainsim.game.trainer.frameloop import FixedStepper
from chainsim.game.trainer.headless import build_app
from chainsim.systems.engine import argtypes
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.haptics import simdevice as D
from chainsim.systems.engine.haptics.servo import warm
from chainsim.tools.bench.needle import bench_of, needle_packs

HELP = "the haptic servo loop at 1 kHz beside a running 60 Hz scene with tissue: tick periods, force error"
FPS = 60.0
TARGET_P99_MS = 1.2
TARGET_MAX_MS = 2.0


def add_arguments(p) -> None:
    p.add_argument("--pack", default="prp", help="a needle pack with tissue (default prp)")
    p.add_argument(
        "--speed", type=argtypes.real(1.0, 100.0), default=10.0, metavar="MM_S", help="insertion speed (default 10)"
    )
    p.add_argument("--servo", choices=("kernel", "python"), default="kernel", help="how the loop runs (default kernel)")
    p.add_argument(
        "--spin-us", type=argtypes.real(0.0, 900.0), default=0.0, metavar="US",
        help="spin this long before each tick instead of sleeping (default 0)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the figures as one JSON object")


def _percentiles(x, qs) -> list[float]:
    return [float(np.percentile(x, q)) for q in qs] if len(x) else [float("nan")] * len(qs)


def run_scene(pack: str, root: Path, manifest: dict, speed: float, servo: str, spin_us: float) -> dict:
    """The scene and the servo together until the trajectory is done; the figures."""
    events, depth, _reached = bench_of(pack, manifest).insertion(root, manifest)
    events = [(t, ev) for t, ev in events if not (isinstance(ev, Widget) and ev.name == "insert")]
    traj = D.scripted(D.insertion(depth, speed, wait=1.3))  # the trajectory starts at placement, aims at 1.2 s
    app = build_app(pack, save="a benchmark saves nothing", headless=False)
    try:
        link = plugins.attach_device(app, "sim", realtime=True, mode=servo, traj=traj)
        link.servo.ctl[4] = int(spin_us * 1e3)  # CT_SPIN
        app.resource(PendingInput).extend(events)
        stepper = FixedStepper(app)
        step_ms, frames = [], 0
        start = last = due = time.perf_counter()
        while link.servo.ticks < len(traj) + 200 and time.perf_counter() - start < 120.0:
            now = time.perf_counter()
            steps = stepper.advance(now - last)
            if steps:
                step_ms.append((time.perf_counter() - now) * 1e3 / steps)
            last = now
            frames += 1
            due = max(due + 1.0 / FPS, time.perf_counter())  # a late frame is not made up by hurried ones
            time.sleep(max(0.0, due - time.perf_counter()))
        seconds = time.perf_counter() - start
        stats = link.servo.stats()
        scheduling = link.servo.scheduling
    finally:
        app.close()
    err = np.array([abs(a - b) for a, b, _moved in link.errors])
    moving = np.array([abs(a - b) for a, b, moved in link.errors if moved])
    p50, p90 = _percentiles(step_ms, (50, 90))
    e50, e99 = _percentiles(moving, (50, 99))
    a50, a99 = _percentiles(err, (50, 99))
    return {
        **stats,
        "servo": servo,
        "scheduling": scheduling,
        "scene_fps": frames / seconds,
        "step_ms_p50": p50,
        "step_ms_p90": p90,
        "force_pairs": int(len(moving)),
        "force_error_N_p50": e50,
        "force_error_N_p99": e99,
        "force_error_N_max": float(moving.max()) if len(moving) else float("nan"),
        "force_pairs_all": int(len(err)),
        "force_error_all_N_p50": a50,
        "force_error_all_N_p99": a99,
    }


def run(args) -> int:
    packs = {name: (name, root, manifest) for name, root, manifest in needle_packs("")}
    if args.pack not in packs:
        raise UserError(f"--pack: expected a needle pack with tissue ({', '.join(packs)}), got {args.pack!r}")
    pack, root, manifest = packs[args.pack]
    warm()  # nothing compiles while the loop runs
    load0 = os.getloadavg()
    out = run_scene(pack, root, manifest, args.speed, args.servo, args.spin_us)
    out.update(pack=pack, cpus=os.cpu_count(), load_before=list(load0), load_after=list(os.getloadavg()))
    out["meets_targets"] = bool(out["period_ms_p99"] <= TARGET_P99_MS and out["period_ms_max"] <= TARGET_MAX_MS)
    if args.json:
        print(json.dumps(out, sort_keys=True))
        return 0
    print(
        f"{pack}: {out['ticks']} ticks ({out['servo']}, {out['scheduling']}) beside the scene at "
        f"{out['scene_fps']:.1f} frames/s (a simulation step {out['step_ms_p50']:.1f} ms median, "
        f"{out['step_ms_p90']:.1f} p90)\n"
        f"  tick period ms: median {out['period_ms_p50']:.3f}, p99 {out['period_ms_p99']:.3f}, "
        f"p99.9 {out['period_ms_p999']:.3f}, worst {out['period_ms_max']:.3f}; missed {out['missed_ticks']}, "
        f"later than 2 ms {out['late_ticks_2ms']} (targets: p99 <= {TARGET_P99_MS}, none > {TARGET_MAX_MS})\n"
        f"  force error, local model vs the simulation at the same depth, needle moving ({out['force_pairs']} "
        f"steps): median {out['force_error_N_p50']:.3f} N, p99 {out['force_error_N_p99']:.3f}, worst "
        f"{out['force_error_N_max']:.3f}; every step ({out['force_pairs_all']}): median "
        f"{out['force_error_all_N_p50']:.3f}, p99 {out['force_error_all_N_p99']:.3f}\n"
        f"  load average {load0[0]:.2f} before, {out['load_after'][0]:.2f} after, on {out['cpus']} CPUs"
    )
    return 0

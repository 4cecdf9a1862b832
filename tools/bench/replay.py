"""`chainsim bench replay`: how fast the records server's scoring replay runs a trainee's window session.

The records server scores an upload by replaying its recording headless
(``chainsim.game.server.scoring.replay_record``), so a class that saves at the end of a session
waits for its sessions' replays. This bench makes such sessions and times their replays:

1. For each needle pack (prp, mental-block), the correct attempt as device input at the window:
   prp's own ``scripts/correct-mouse.toml``, or the pack's ``scripts/correct.toml`` turned into
   clicks and drags (``chainsim.game.trainer.windowform``); a click on Save is added when the last
   press is not on it.
2. The gestures spread over a session of ``--session-minutes`` (default 10): idle time between them,
   the pointer wandering now and then, and travelling to each target before it is pressed.
3. The session recorded as the window records it: a headless App of the pack driven frame by frame
   (``chainsim.game.trainer.frameloop.FixedStepper``, 60 frames a second), each event handed in at the
   frame it falls in, and the upload's evidence (``game.trainer.headless.attempt_evidence``) taken when
   the Save is handled. This App does all the window's work (``replay=False``).
4. ``replay_record`` on the recording, each repeat in a fresh process pinned to one core (as a
   scorer gets when every scorer is busy), after its imports: simulated seconds per CPU second of
   that process (every thread's time) and per wall second, median of ``--repeats``.

Each pack runs with its tissue and without it: a copy of the pack with the tissue bodies removed
(the same cut as the needle procedure's unit tests make: no ``tissue_*`` meshes and entities, no
``[needle_tissue]`` or ``[tissue_layers]``, the needle inserting in one step). Every replay's saved
figures are compared with the recorded session's, and its world digest at the Save with the one
the recording carries (``same``: both equal).
"""

from __future__ import annotations

import json
import multiprocessing
import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from chainsim.systems.engine.argtypes import count, real
from chainsim.systems.engine.errors import UserError

HELP = "time the records server's scoring replay of a window session (simulated s per CPU s)"
PACKS = ("prp", "mental-block")
#: the window's frame rate while recording (a 60 Hz display)
FRAME_S = 1.0 / 60.0
#: the pointer's path to a target: moves this long before the press, one per frame
APPROACH_S = 0.5
#: a wander of the pointer while the trainee reads or thinks: this long, every WANDER_EVERY_S seconds or so
WANDER_S = 0.4
WANDER_EVERY_S = (3.0, 8.0)
SEED = 20240611


def add_arguments(p) -> None:
    p.add_argument(
        "--session-minutes", type=real(0.2, 45.0, what="minutes"), default=10.0, metavar="M",
        help="each session's length: the attempt's gestures spread over M minutes (default 10; 0.2-45)",
    )  # fmt: skip
    p.add_argument("--repeats", type=count(1, 20), default=3, help="replays timed per session, median (default 3)")
    p.add_argument("--packs", default=",".join(PACKS), help=f"packs, comma-separated (default {','.join(PACKS)})")
    p.add_argument(
        "--tissue", choices=("both", "with", "without"), default="both",
        help="run each pack with its tissue, without it, or both (default both)",
    )  # fmt: skip
    p.add_argument(
        "--threads", type=count(1, 64), default=None,
        help="numba threads in the replay process (default: numba's own count)",
    )  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the result as one JSON object")


# -- the packs ------------------------------------------------------------------------------------


def without_tissue(text: str) -> str:
    """A needle pack's pack.toml less its soft tissue: no tissue meshes, entities, [needle_tissue] or
    [tissue_layers], the needle inserting in one step (insert_speed 0) as in a pack without tissue."""
    out, skip = [], False
    for line in text.splitlines():
        if line.startswith("["):
            name = line.strip("[] ")
            skip = name.startswith(("meshes.tissue_", "entities.tissue_", "needle_tissue", "tissue_layers."))
        if line.startswith("insert_speed = "):
            line = "insert_speed = 0.0"
        if not skip:
            out.append(line)
    return "\n".join(out) + "\n"


def pack_variant(name: str, tissue: bool, folder: Path) -> tuple[Path, list[str]]:
    """(pack folder, pack paths) of built-in pack ``name``, as shipped or copied into ``folder`` without tissue."""
    from chainsim.game.packs.discovery import BUILTIN_DIR  # noqa: PLC0415 - loaded when the bench runs

    source = BUILTIN_DIR / name
    if not (source / "pack.toml").is_file():
        raise UserError(f"the built-in pack {name!r} is missing; reinstall chainsim")
    if tissue:
        return source, [str(BUILTIN_DIR)]
    root = folder / "no-tissue" / name
    shutil.copytree(source, root, ignore=shutil.ignore_patterns("__pycache__", ".*"))
    manifest = root / "pack.toml"
    manifest.write_text(without_tissue(manifest.read_text(encoding="utf-8")), encoding="utf-8")
    # the packs it requires (mental-block requires prp) are found among the built-in ones
    return root, [str(BUILTIN_DIR)]


# -- the session ----------------------------------------------------------------------------------


def attempt_gestures(app, root: Path) -> list[list[tuple[float, Any]]]:
    """The pack's correct attempt as device input, one list per gesture (each begins with the pointer's
    move to its target), ending with a press on Save."""
    from chainsim.components.input_events import MouseButton, MouseMove  # noqa: PLC0415
    from chainsim.game.trainer import windowform  # noqa: PLC0415
    from chainsim.game.trainer.inputscript import load_script  # noqa: PLC0415

    mouse = root / "scripts" / "correct-mouse.toml"
    events = load_script(mouse) if mouse.is_file() else windowform.gestures(
        app, load_script(root / "scripts" / "correct.toml"), windowform.INSTANT
    )  # fmt: skip
    presses = [ev for _, ev in events if isinstance(ev, MouseButton) and ev.pressed]
    if not presses or widget_at(app, presses[-1].x, presses[-1].y) != "save":
        events = events + windowform.save_click(app, events[-1][0], windowform.INSTANT)
    out: list[list[tuple[float, Any]]] = []
    for t, ev in events:
        if isinstance(ev, MouseMove) or not out:
            out.append([])
        out[-1].append((t, ev))
    return out


def widget_at(app, x: float, y: float) -> str:
    """The name of the panel widget under window point (x, y), "" when none."""
    from chainsim.systems.view.cameras import ViewState  # noqa: PLC0415
    from chainsim.systems.view.ui import widgets as wd  # noqa: PLC0415

    vs = app.resource(ViewState)
    vp = vs.at(x, y)
    p = wd.hit(vs.panels.get(vp.name, []), x, y) if vp is not None and vp.kind == "panel" else None
    return p.spec["name"] if p is not None else ""


def stretched(gestures: list[list[tuple[float, Any]]], seconds: float, size: tuple[float, float]) -> list:
    """The gestures spread evenly over ``seconds``, as a person takes them: each keeps its own timing; the
    pointer travels to its target over APPROACH_S before it, and wanders a little now and then between."""
    from chainsim.components.input_events import MouseMove  # noqa: PLC0415

    rng = np.random.default_rng(SEED)
    n = len(gestures)
    first, last = 2.0, max(seconds - 1.0, 2.0 + n)
    starts = [first + (last - first) * i / max(n - 1, 1) for i in range(n)]
    out: list[tuple[float, Any]] = []
    x, y = size[0] / 2, size[1] / 2
    idle_from = 0.5
    for start, gesture in zip(starts, gestures, strict=True):
        t = idle_from + rng.uniform(*WANDER_EVERY_S)
        while t + WANDER_S < start - APPROACH_S - 0.5:
            for k in range(int(WANDER_S / FRAME_S)):
                x = float(np.clip(x + rng.normal(0.0, 8.0), 0.0, size[0] - 1))
                y = float(np.clip(y + rng.normal(0.0, 8.0), 0.0, size[1] - 1))
                out.append((t + k * FRAME_S, MouseMove(round(x), round(y))))
            t += WANDER_S + rng.uniform(*WANDER_EVERY_S)
        t0 = gesture[0][0]
        aim = gesture[0][1]
        frames = int(APPROACH_S / FRAME_S)
        for k in range(1, frames):
            f = k / frames
            out.append(
                (start - APPROACH_S + k * FRAME_S, MouseMove(round(x + f * (aim.x - x)), round(y + f * (aim.y - y))))
            )
        out += [(start + t - t0, ev) for t, ev in gesture]
        x, y = gesture[-1][1].x, gesture[-1][1].y
        idle_from = start + gesture[-1][0] - t0
    out.sort(key=lambda te: te[0])
    return out


def record_session(root: Path, pack_paths: list[str], minutes: float) -> dict:
    """The stretched session made at the window (module docstring, steps 1-3): ``{"recording"}`` (the
    upload's compressed text), ``"record"`` (the figures the Save made), ``"digest"``, ``"events"``,
    ``"simulated_s"``."""
    from chainsim.components.resources import PendingInput, Records, Settings  # noqa: PLC0415
    from chainsim.game.packs import pack as packs  # noqa: PLC0415
    from chainsim.game.records import provenance  # noqa: PLC0415
    from chainsim.game.trainer.frameloop import FixedStepper  # noqa: PLC0415
    from chainsim.game.trainer.headless import app_for_pack, attempt_evidence  # noqa: PLC0415

    pack = packs.load(root, pack_paths)
    # the window's App does all its work: replay=False, though this one draws and saves nothing itself
    app = app_for_pack(pack, None, save="a benchmark's session saves nothing", replay=False)
    try:
        saved: list[dict] = []
        evidence: dict = {}

        def save_attempt(class_name: str, trainee: str, record: dict) -> int:
            evidence.update(attempt_evidence(app, pack, None))  # as a records server's Records takes it
            saved.append(record)
            return len(saved)

        app.insert_resource(Records(save_attempt=save_attempt, list_attempts=lambda c, t: [], where="bench"))
        size = tuple(app.resource(Settings).get("window_size", (1280, 800)))
        events = stretched(attempt_gestures(app, root), minutes * 60.0, size)
        pending = app.resource(PendingInput)
        stepper = FixedStepper(app)
        k, end = 0, events[-1][0] + 2.0
        while not saved and app.time.sim_time < end:
            # the window stamps each event with the simulated time of the frame it arrives in
            while k < len(events) and events[k][0] <= app.time.sim_time:
                pending.push(app.time.sim_time, events[k][1])
                k += 1
            stepper.advance(FRAME_S)
    finally:
        app.close()
    if not saved:
        raise UserError(f"pack {pack.name!r}: the bench's session never saved (its last press is not on Save)")
    recording = provenance.decode_recording(evidence["recording"])
    return {
        "recording": evidence["recording"],
        "record": saved[-1],
        "digest": recording["digest"],
        "events": len(recording["event"]),
        "simulated_s": recording["steps"] * recording["dt"],
    }


# -- timing the replay ------------------------------------------------------------------------------


def _timed_replay(text: str, root: str, pack_paths: list[str]) -> dict:
    """In a fresh process: replay_record on one core, its CPU and wall seconds. The imports a scorer's
    process pays once are made first and not counted (NUMBA_NUM_THREADS comes from the parent)."""
    import chainsim.game.trainer.headless  # noqa: F401, PLC0415 - what replay_record imports on its first call
    from chainsim.game.server.scoring import replay_record  # noqa: PLC0415
    from chainsim.systems.procedures import PROCEDURES  # noqa: PLC0415

    for proc in PROCEDURES.values():  # whichever procedure the pack runs, its systems are imported already
        proc.systems()

    if hasattr(os, "sched_setaffinity"):  # one core, as one scorer gets when every scorer is busy
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    t0, c0 = time.perf_counter(), time.process_time()
    out = replay_record(text, root, pack_paths)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"cpu_s": cpu, "wall_s": wall, "result": out}


def canonical(record: dict) -> str:
    """An attempt record as text, for an exact comparison."""
    return json.dumps(record, sort_keys=True, default=lambda v: v.tolist() if hasattr(v, "tolist") else repr(v))


def time_replays(session: dict, root: Path, pack_paths: list[str], repeats: int, threads: int | None) -> dict:
    """Median simulated seconds per CPU second and per wall second of ``repeats`` replays of ``session``,
    and whether every replay saved the recorded figures and reached the recorded digest."""
    env = os.environ.copy()
    if threads is not None:  # set before the child imports numba, so its thread pool is that size
        os.environ["NUMBA_NUM_THREADS"] = str(threads)
    ctx = multiprocessing.get_context("spawn")
    runs = []
    try:
        for _ in range(repeats):
            with ctx.Pool(1) as pool:
                runs.append(pool.apply(_timed_replay, (session["recording"], str(root), pack_paths)))
    finally:
        os.environ.clear()
        os.environ.update(env)
    sim = session["simulated_s"]
    cpu = statistics.median(r["cpu_s"] for r in runs)
    wall = statistics.median(r["wall_s"] for r in runs)
    results = [r["result"] for r in runs]
    # replay_record returns the record, or {"record", "digest_ok", ...} where the scorer checks digests
    records = [r.get("record", r) for r in results]
    digests = [r.get("digest_ok") for r in results]
    return {
        "cpu_s": round(cpu, 3),
        "wall_s": round(wall, 3),
        "sim_s_per_cpu_s": round(sim / cpu, 1),
        "sim_s_per_wall_s": round(sim / wall, 1),
        "cpu_s_each": [round(r["cpu_s"], 3) for r in runs],
        "same_figures": all(canonical(r) == canonical(session["record"]) for r in records),
        "same_digest": None if None in digests else all(digests),
    }


# -- the command ----------------------------------------------------------------------------------


def run_bench(packs: list[str], variants: list[bool], minutes: float, repeats: int, threads: int | None) -> dict:
    rows = []
    with tempfile.TemporaryDirectory(prefix="chainsim-bench-replay-") as tmp:
        for name in packs:
            for tissue in variants:
                root, pack_paths = pack_variant(name, tissue, Path(tmp))
                t0 = time.process_time()
                session = record_session(root, pack_paths, minutes)
                recorded = time.process_time() - t0
                timing = time_replays(session, root, pack_paths, repeats, threads)
                rows.append(
                    {
                        "pack": name,
                        "tissue": tissue,
                        "simulated_s": round(session["simulated_s"], 2),
                        "events": session["events"],
                        "record_cpu_s": round(recorded, 2),
                        **timing,
                    }
                )
    return {
        "session_minutes": minutes,
        "repeats": repeats,
        "numba_threads": threads,
        "one_core": hasattr(os, "sched_setaffinity"),
        "runs": rows,
    }


def run(args) -> int:
    packs = [p.strip() for p in args.packs.split(",") if p.strip()]
    unknown = [p for p in packs if p not in PACKS]
    if not packs or unknown:
        got = f"got {', '.join(map(repr, unknown))}" if unknown else "got none"
        raise UserError(f"--packs: the needle packs to time, comma-separated, of {', '.join(PACKS)}; {got}")
    variants = {"both": [True, False], "with": [True], "without": [False]}[args.tissue]
    result = run_bench(packs, variants, args.session_minutes, args.repeats, args.threads)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(
        f"scoring replay of {args.session_minutes:g}-minute window sessions, median of {args.repeats}, "
        f"{'one core' if result['one_core'] else 'unpinned'}:"
    )
    heads = ("sim s", "events", "CPU s", "sim/CPU", "wall s", "sim/wall")
    print(f"{'pack':<14}{'tissue':<8}" + "".join(f"{h:>9}" for h in heads) + "  same")
    for r in result["runs"]:
        same = "yes" if r["same_figures"] and r["same_digest"] is not False else "NO"
        print(
            f"{r['pack']:<14}{'with' if r['tissue'] else 'without':<8}{r['simulated_s']:>9.1f}{r['events']:>9}"
            f"{r['cpu_s']:>9.2f}{r['sim_s_per_cpu_s']:>9.1f}{r['wall_s']:>9.2f}{r['sim_s_per_wall_s']:>9.1f}  {same}"
        )
    bad = [r for r in result["runs"] if not r["same_figures"] or r["same_digest"] is False]
    if bad:
        raise UserError(
            f"{len(bad)} replay(s) did not reproduce the recorded session (figures or digest): "
            + ", ".join(f"{r['pack']} {'with' if r['tissue'] else 'without'} tissue" for r in bad)
        )
    return 0

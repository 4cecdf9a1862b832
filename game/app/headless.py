"""Building an App for a pack, and headless runs that write `summary.json`.

`build_app` is the one way every front end (headless run, replay, window, snapshot, tests) turns
`PACK[/SCENE]` into a running App: validate the pack, spawn the scene, install the plugins it needs.
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Any

import esper
import numpy as np

from chainsim.components.core import Name
from chainsim.components.deformable import Deformable
from chainsim.components.resources import Assessment, PackResource, PendingInput, RunInfo, Settings
from chainsim.engine.errors import UserError
from chainsim.game.app import plugins
from chainsim.game.app.core import App
from chainsim.game.app.digest import world_digest
from chainsim.game.app.inputscript import load_script, write_recording
from chainsim.game.app.loader import spawn_scene
from chainsim.game.packs import pack as packs
from chainsim.game.records.remote import remote_records
from chainsim.game.records.store import local_records
from chainsim.systems.input import InputLog


def build_app(
    ref: str,
    *,
    pack_paths=(),
    settings: dict | None = None,
    dt: float | None = None,
    render: bool = False,
    headless: bool = True,
    out_dir: str | None = None,
    screenshot_every: int = 0,
    size: tuple[int, int] | None = None,
) -> App:
    root, scene = packs.resolve(ref, pack_paths)
    pack = packs.load(root)
    pack_settings = dict(pack.section("settings"))
    pack_settings.update(settings or {})
    if size is not None:
        pack_settings["window_size"] = [float(size[0]), float(size[1])]
    step = dt if dt is not None else float(pack_settings.get("dt", 1.0 / 120.0))
    app = App(dt=step, settings=pack_settings, name=pack.name)
    try:
        spawn_scene(app, pack, scene)
        scene_name = app.resource(PackResource).scene
        app.insert_resource(RunInfo(ref, pack.name, scene_name, headless, render, out_dir, screenshot_every))
        app.insert_resource(Assessment())
        if pack_settings.get("records"):  # a records server (queueing in the local store when offline)
            app.insert_resource(remote_records(pack_settings["records"], pack_settings.get("db") or None))
        else:
            app.insert_resource(local_records(pack_settings.get("db") or None))
        plugins.install(app, pack.manifest["pack"].get("procedure", ""), render=render)
    except BaseException:
        app.close()
        raise
    return app


def _progress(done: int, total: int) -> None:
    if sys.stderr.isatty() and total >= 2000 and done % max(total // 20, 1) == 0:
        print(f"\r  step {done}/{total}", end="", file=sys.stderr, flush=True)


def run_pack(
    ref: str,
    steps: int | None = None,
    *,
    script: str | None = None,
    events=None,
    record: str | None = None,
    out: str | None = None,
    pack_paths=(),
    settings: dict | None = None,
    dt: float | None = None,
    render: bool = False,
    screenshot_every: int = 0,
    size: tuple[int, int] | None = None,
) -> dict[str, Any]:
    """Run a pack headless for `steps` fixed steps; returns (and writes to OUT/summary.json) the summary."""
    if steps is not None and steps < 0:
        raise UserError(f"--steps must be >= 0, got {steps}")
    if out:
        try:
            Path(out).mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise UserError(f"--out {out}: cannot create folder ({e.strerror})") from None
    timed = list(events or [])
    if script:
        timed = load_script(script)
    app = build_app(
        ref,
        pack_paths=pack_paths,
        settings=settings,
        dt=dt,
        render=render or screenshot_every > 0,
        out_dir=out,
        screenshot_every=screenshot_every,
        size=size,
    )
    try:
        pres: PackResource = app.resource(PackResource)
        if not script and events is None and pres.scene_spec.get("script"):
            timed = load_script(pres.pack.file(pres.scene_spec["script"]))
        app.resource(PendingInput).extend(timed)
        n = int(steps if steps is not None else app.resource(Settings).get("steps", 600))
        for i in range(n):
            app.update(app.time.dt)
            _progress(i + 1, n)
        digest = world_digest(app)
        log = app.get_resource(InputLog)
        summary = {
            "pack": pres.pack.name,
            "scene": pres.scene,
            "steps": app.time.tick,
            "frames": app.time.frame,
            "dt": app.time.dt,
            "simulated_time_s": app.time.sim_time,
            "systems": app.system_stats(),
            "digest": digest,
            "events_applied": len(log.items) if log else 0,
        }
        models = body_models(app)
        if models:
            summary["models"] = models
        assessment = app.resource(Assessment).values
        if assessment:
            summary["assessment"] = _jsonable(assessment)
        if record:
            write_recording(
                record,
                pack=ref,
                scene=pres.scene,
                dt=app.time.dt,
                steps=n,
                events=log.items if log else timed,
                digest=digest,
                settings=settings,
            )
        if out:
            tmp = Path(out) / "summary.json.tmp"
            tmp.write_text(json.dumps(summary, indent=2, sort_keys=True), encoding="utf-8")
            os.replace(tmp, Path(out) / "summary.json")
        return summary
    finally:
        app.close()


def body_models(app) -> dict:
    """Which deformation model each soft body runs, and why (the pack, --model, or the auto choice)."""
    with app.active():
        return {
            esper.component_for_entity(ent, Name).value: {"model": d.model_used, "why": d.model_reason}
            for ent, d in esper.get_component(Deformable)
        }


def _jsonable(v):

    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    return v

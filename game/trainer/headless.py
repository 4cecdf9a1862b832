"""Building an App for a pack, and headless runs that write `summary.json`.

`build_app` is the one way every front end (headless run, replay, window, snapshot, tests) turns
`PACK[/SCENE]` into a running App: validate the pack, spawn the scene, install the plugins it needs.
`start_problems` starts each scene of a pack the same way without stepping, which is how `validate`
knows that a pack it passes will run. Settings a user gives (records database, class, trainee) are
checked before anything runs (`check_user_settings`), and a run whose save failed ends with exit 2.
"""

from __future__ import annotations

import json
import signal
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import Name
from chainsim.components.digest import world_digest
from chainsim.components.input_events import PickPoint
from chainsim.components.loader import spawn_scene
from chainsim.components.resources import (
    Assessment,
    EntityIndex,
    FailedSaves,
    PackResource,
    PendingInput,
    Records,
    RunInfo,
    RunOutputs,
    Settings,
)
from chainsim.game.common.outputs import check_output_file, prepare_output_dir, write_text_atomic
from chainsim.game.packs import pack as packs
from chainsim.game.records import provenance, remote
from chainsim.game.records import store as records
from chainsim.game.records.remote import remote_records
from chainsim.game.records.store import local_records
from chainsim.game.records.validate import clean_name
from chainsim.game.trainer import plugins
from chainsim.game.trainer.inputscript import load_script, recording_data, write_recording
from chainsim.game.trainer.options import MODEL_FLAG_CHOICES
from chainsim.systems.engine import limits
from chainsim.systems.engine.errors import Interrupted, UserError
from chainsim.systems.engine.progress import progress
from chainsim.systems.motion.input import InputLog
from chainsim.systems.tissue.deformable import Deformable
from chainsim.systems.view.picking import entity_surface


@dataclass(slots=True)
class SaveReport:
    """Where each Save of a run on a records server went, one line each (`chainsim run` prints them)."""

    lines: list[str] = field(default_factory=list)


#: settings a user (or a recording) may give on top of the pack's own: name -> type
USER_SETTINGS = {"db": str, "records": str, "class": str, "trainee": str, "model": str, "fluoro_first": bool}


def check_user_settings(settings: dict | None, where: str = "settings") -> dict:
    """The user's settings, checked: known keys and types, class/trainee names, a usable database path.

    Nothing is created or written here; a database that does not exist yet must have an existing,
    writable folder (it is created, with a warning, when the first attempt is saved).
    """
    out: dict = {}
    if settings is None:
        return out
    if not isinstance(settings, dict):
        raise UserError(f"{where}: expected a table of settings, got {type(settings).__name__}")
    for key, value in settings.items():
        kind = USER_SETTINGS.get(key)
        if kind is None:
            raise UserError(f"{where}: unknown setting {key!r}; known: {', '.join(USER_SETTINGS)}")
        if not isinstance(value, kind):
            raise UserError(f"{where}: setting {key!r} must be {kind.__name__}, got {type(value).__name__}")
        if key in ("class", "trainee"):
            value = clean_name(key, value)
        elif key == "db":
            records.check_target(str(value))  # str(): a str already (checked above), which mypy cannot follow
        elif key == "records":
            value = remote.server_url(str(value))
        elif key == "model" and value not in MODEL_FLAG_CHOICES:
            raise UserError(f"{where}: setting 'model' must be one of {', '.join(MODEL_FLAG_CHOICES)}, got {value!r}")
        out[key] = value
    return out


def check_dt(dt, where: str = "--dt") -> float:
    """A fixed step within [MIN_DT, MAX_DT] seconds."""
    try:
        return limits.number(dt, limits.MIN_DT, limits.MAX_DT)
    except limits.LimitError as e:
        raise UserError(f"{where}: the fixed step in seconds: {e}") from None


def app_for_pack(
    pack: packs.Pack,
    scene: str | None,
    *,
    settings: dict | None = None,
    dt: float | None = None,
    render: bool = False,
    headless: bool = True,
    out_dir: str | None = None,
    screenshot_every: int = 0,
    size: tuple[int, int] | None = None,
    save: str = "",
    replay: bool | None = None,
) -> App:
    """A started App for a validated pack's scene: spawned, plugins installed, not stepped.

    `save`, when given, is why this run saves nothing (a replay, a protocol trial): its Records then
    refuse every write and list no attempts, and the records database is never opened.
    `replay`: the systems skip the work that only feeds a window (`RunInfo.replay`); by default a
    run that saves nothing and draws nothing (`save` given, `render` off) is one.
    """
    pack_settings = dict(pack.section("settings"))
    pack_settings.update(check_user_settings(settings))
    if size is not None:
        pack_settings["window_size"] = [float(size[0]), float(size[1])]
    step = check_dt(dt) if dt is not None else float(pack_settings.get("dt", 1.0 / 120.0))
    app = App(dt=step, settings=pack_settings, name=pack.name)
    try:
        app.insert_resource(FailedSaves())
        app.insert_resource(RunOutputs())
        spawn_scene(app, pack, scene)
        scene_name = app.resource(PackResource).scene
        lean = bool(save) and not render if replay is None else replay
        app.insert_resource(RunInfo(pack.name, scene_name, headless, render, out_dir, screenshot_every, lean))
        app.insert_resource(Assessment())
        if save:
            app.insert_resource(refusing_records(save))
        elif pack_settings.get("records"):  # a records server (queueing in the local store when offline)
            # the server scores the attempt by replaying this session, so each save carries its recording
            evidence = lambda: attempt_evidence(app, pack, settings)  # noqa: E731
            said = app.insert_resource(SaveReport()).lines
            server, db = pack_settings["records"], pack_settings.get("db") or None
            app.insert_resource(remote_records(server, db, evidence, said))
        else:  # each attempt keeps the recording of its session, as a records server keeps an upload's
            recording = lambda: attempt_recording(app, pack, settings)  # noqa: E731
            app.insert_resource(local_records(pack_settings.get("db") or None, recording))
        plugins.install(app, pack.manifest["pack"].get("procedure", ""), render=render)
    except BaseException:
        app.close()
        raise
    return app


def attempt_evidence(app: App, pack: packs.Pack, settings: dict | None) -> dict:
    """What an upload carries for the records server to replay: the session so far, and the pack's identity.

    Called while the Save is handled, so the recording runs from the session's start to the step that
    saves (the state an attempt starts from is whatever the session's earlier attempts left)."""
    return {"recording": attempt_recording(app, pack, settings), "pack_identity": provenance.pack_identity(pack)}


def attempt_recording(app: App, pack: packs.Pack, settings: dict | None) -> str:
    """The session so far as a compressed recording (``provenance.encode_recording``), as a Save keeps it."""
    log = app.get_resource(InputLog)
    recording = recording_data(
        pack=pack.name,
        scene=app.resource(PackResource).scene,
        dt=app.time.dt,
        steps=app.time.tick,
        events=list(log.items) if log else [],
        digest=world_digest(app),
        settings={k: v for k, v in (settings or {}).items() if k in ("class", "trainee", "model")},
    )
    trial = app.resource(Settings).values.get("protocol")
    if isinstance(trial, dict):  # a study's trial: the records server checks it against its register
        recording["protocol"] = {k: trial.get(k) for k in ("study", "participant", "order", "trial", "condition")}
        recording["protocol"].update(
            practice=bool(trial.get("practice")), slot=(trial.get("allocation") or {}).get("slot")
        )
    return provenance.encode_recording(recording)


def refusing_records(reason: str) -> Records:
    """Records that save nothing and list nothing, saying `reason` (replays, protocol trials)."""

    def save_attempt(class_name: str, trainee: str, record: dict) -> int:
        raise UserError(f"not saved: {reason}")

    return Records(save_attempt=save_attempt, list_attempts=lambda c, t: [], where="nowhere", refuses=reason)


def build_app(ref: str, *, pack_paths=(), scene: str | None = None, **kwargs) -> App:
    """`PACK[/SCENE]` or a pack folder -> a started App (see `app_for_pack` for the keyword arguments);
    `scene`, when given, is the scene to start whatever the reference names (a replay's recorded one)."""
    root, ref_scene = packs.resolve(ref, pack_paths)
    return app_for_pack(packs.load(root, pack_paths), scene or ref_scene, **kwargs)


def check_events(app: App, events, where: str) -> None:
    """Everything in a script that the run would refuse mid-way, refused before it starts: picks must
    name an entity of the scene with a surface to pick on, and the procedure checks the values of the
    events it reads (plugins.event_check)."""
    index: EntityIndex = app.resource(EntityIndex)
    pres: PackResource = app.resource(PackResource)
    check = plugins.event_check(pres.pack.manifest["pack"].get("procedure", ""))
    for t, ev in events:
        if isinstance(ev, PickPoint):
            ent = index.get(ev.entity)
            if ent is None:
                raise UserError(
                    f"{where}: pick event at t={t:g} names entity '{ev.entity}', which is not in scene "
                    f"'{pres.scene}' (entities: {', '.join(sorted(index.by_name))})"
                )
            with app.active():
                surface = entity_surface(app, ent)
            if surface is None:
                raise UserError(
                    f"{where}: pick event at t={t:g} names entity '{ev.entity}', which has no triangle mesh to pick on"
                )
        if check is not None:
            try:
                check(ev)
            except UserError as e:
                raise UserError(f"{where}: event at t={t:g}: {e}") from None


def validate_pack(root, pack_paths=()) -> tuple[packs.Pack | None, list[packs.Problem]]:
    """Everything `run` would refuse, as `chainsim validate` reports it: the pack's manifest and files
    (chainsim.game.packs.pack.validate), then every scene started as `run` starts it, without stepping.
    """
    pack, problems = packs.validate(root, pack_paths=pack_paths)
    if pack is None:
        return None, problems
    problems = [packs.problem_at(pack, scene, message) for scene, message in start_problems(pack)]
    return (None, problems) if problems else (pack, [])


def start_problems(pack: packs.Pack) -> list[tuple[str, str]]:
    """(scene, message) for every scene that `run` would refuse to start, and for its script."""
    out = []
    scenes: list[str | None] = [*pack.scene_names()] or [None]  # None: the pack's one unnamed scene
    for scene in scenes:
        name = scene or "main"
        try:
            app = app_for_pack(pack, scene, save="validation saves nothing")
        except UserError as e:
            out.append((name, str(e)))
            continue
        try:
            spec = app.resource(PackResource).scene_spec
            if spec.get("script"):
                where = f"scenes.{name}.script"
                try:
                    events = load_script(pack.file(spec["script"]))
                except UserError as e:
                    raise UserError(f"{where}: {e}") from None
                check_events(app, events, where)
        except UserError as e:
            out.append((name, str(e)))
        finally:
            app.close()
    return out


def _steps(total: int):
    """The steps of a run; long runs show a progress bar (chainsim.systems.engine.progress) that ends its line."""
    return progress(range(total), desc="steps", unit="step") if total >= 2000 else range(total)


class _StopAtStep:
    """Ctrl-C while a run steps: the step under way finishes and the run stops after it (`asked`), so
    what it writes is a whole step's world; a second Ctrl-C stops at once (KeyboardInterrupt).

    Only in the main thread (the only one Python delivers signals to), and never over a SIGINT that
    was set to be ignored (a run started in the background)."""

    def __init__(self) -> None:
        self.asked = False
        self._installed = False
        self._before: Any = None

    def _ask(self, signum, frame) -> None:
        if self.asked:
            raise KeyboardInterrupt
        self.asked = True

    def __enter__(self) -> _StopAtStep:
        if threading.current_thread() is threading.main_thread():
            self._before = signal.getsignal(signal.SIGINT)
            if self._before is not signal.SIG_IGN:
                signal.signal(signal.SIGINT, self._ask)
                self._installed = True
        return self

    def __exit__(self, *exc) -> None:
        if self._installed:  # a handler set outside Python reads as None: the default is put back then
            signal.signal(signal.SIGINT, signal.SIG_DFL if self._before is None else self._before)


def _run_steps(app, n: int) -> int:
    """Step `app` `n` times; returns how many steps ran (fewer when Ctrl-C stopped the run)."""
    done, steps = 0, _steps(n)
    try:
        with _StopAtStep() as stop:
            for _ in steps:
                app.update(app.time.dt)
                done += 1
                if stop.asked:
                    break
    finally:
        if hasattr(steps, "close"):
            steps.close()  # the bar ends its line before anything else is said
    return done


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
    save: str = "",
    scene: str | None = None,
    device: str | None = None,
) -> dict[str, Any]:
    """Run a pack headless for `steps` fixed steps; returns (and writes to OUT/summary.json) the summary.

    `save`: why this run saves nothing ("" saves to the records database; see `app_for_pack`).
    `scene`: the scene to run when `ref` is a pack alone (a replay passes the recorded one).
    Ctrl-C ends the run after the step under way: the summary and outputs of the steps run so far are
    written as for a whole run, then `Interrupted` says where it stopped and what was written.
    """
    if steps is not None:
        try:
            steps = limits.whole(steps, 0, limits.MAX_STEPS)
        except limits.LimitError as e:
            raise UserError(f"--steps: {e} (docs/limits.md)") from None
    # every output is checked before the run, so a long run never ends in an unwritable path
    if record:
        check_output_file(record, "--record")
    if out:
        prepare_output_dir(out, "--out")
    timed = list(events or [])
    if script:
        timed = load_script(script)
    app = build_app(
        ref,
        pack_paths=pack_paths,
        scene=scene,
        settings=settings,
        dt=dt,
        render=render or screenshot_every > 0,
        out_dir=out,
        screenshot_every=screenshot_every,
        size=size,
        save=save,
    )
    try:
        if device:
            plugins.attach_device(app, device)
        pres: PackResource = app.resource(PackResource)
        if not script and events is None and pres.scene_spec.get("script"):
            timed = load_script(pres.pack.file(pres.scene_spec["script"]))
        check_events(app, timed, script or "input")
        app.resource(PendingInput).extend(timed)
        n = int(steps if steps is not None else app.resource(Settings).get("steps", 600))
        done = _run_steps(app, n)
        summary = _summary(app)
        if done < n:
            summary["interrupted"] = {"steps_run": done, "steps_asked": n}
        wrote = _write_run(app, summary, ref, settings, record, out, timed, done)
        failed = app.resource(FailedSaves).messages
        more = f" (and {len(failed) - 1} more)" if len(failed) > 1 else ""
        not_saved = f"the attempt was not saved: {failed[0]}{more}" if failed else ""
        if done < n:
            written = f"wrote {', '.join(wrote)}" if wrote else "wrote nothing (--out DIR keeps the summary)"
            raise Interrupted(f"interrupted at step {done} of {n}; {written}" + (f"; {not_saved}" if failed else ""))
        if failed:
            raise UserError(not_saved)
        return summary
    finally:
        app.close()


def _write_run(app, summary: dict, ref: str, settings, record: str | None, out: str | None, timed, steps: int):
    """Write the run's recording of its `steps` (--record) and OUT/summary.json with the procedure's
    files (--out); returns what was written, as the user named it."""
    wrote = []
    pres: PackResource = app.resource(PackResource)
    if record:
        log = app.get_resource(InputLog)
        applied = log.items if log else timed
        write_recording(
            record, pack=ref, scene=pres.scene, dt=app.time.dt, steps=steps, events=applied,
            digest=summary["digest"], settings=settings,
        )  # fmt: skip
        wrote.append(str(record))
    failed = app.resource(FailedSaves).messages
    if failed:
        summary["save_errors"] = list(failed)
    report = app.get_resource(SaveReport)
    if report is not None and report.lines:
        summary["saves"] = list(report.lines)
    if out:
        write_text_atomic(Path(out) / "summary.json", json.dumps(summary, indent=2, sort_keys=True), "--out")
        wrote.append(str(Path(out) / "summary.json"))
        for name, text in app.resource(RunOutputs).files.items():
            write_text_atomic(Path(out) / name, text(), "--out")
            wrote.append(str(Path(out) / name))
    return wrote


def _summary(app) -> dict[str, Any]:
    """What a headless run reports: the pack and scene, steps and time, per-system costs, the world's
    digest, the input applied, the bodies' models and the assessment."""
    digest = world_digest(app)
    pres: PackResource = app.resource(PackResource)
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
    return summary


def body_models(app) -> dict:
    """Which deformation model each soft body runs, and why (the pack, --model, or the auto choice)."""
    with app.active():
        return {
            esper.component_for_entity(ent, Name).value: {"model": d.body.model_used, "why": d.body.model_reason}
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

"""The records server computes each attempt's result: it replays the attempt's recording on its own pack.

An upload (``POST /api/attempts``) carries the simulator's figures, the input recording of the
session up to the Save and the pack's identity (``chainsim.game.records.provenance``). It is
checked at once - the pack must be one this server has, at the same version and with the same
files, and the recording must be a well-formed recording of that pack that reaches a Save -
then committed to the ``uploads`` table (its statements: ``chainsim.game.records.upload_queue``) and
acknowledged (202). Nothing is scored on the request.

``Scorer`` is a bounded pool: ``workers`` threads, each claiming the oldest waiting upload from the
database and replaying it in a process of its own (the ECS world is per process, and a replay is
CPU work that must not hold the server's event loop or its threads). The claim is a row update;
the result - the attempt built from the replay's figures, the client's figures kept beside it,
the fields where they differ, the recording - is inserted in the same transaction that marks the
upload scored, and only if the claim is still this worker's. So each upload becomes at most one
attempt, and a killed server resumes: uploads claimed by a process that is gone (same host) or
whose claim is older than the lease are claimed again. A recording that does not replay to a Save
refuses the upload ("refused", with the reason), which its filer sees through ``GET
/api/uploads/ID`` and the dashboard.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import socket
import threading
import time
import uuid
from pathlib import Path
from typing import Any

from chainsim.game.records import plausible, provenance, upload_queue
from chainsim.game.records.backend import db_errors
from chainsim.game.records.migrations import LEGACY_METRICS
from chainsim.game.records.store import RecordStore
from chainsim.game.records.validate import clean_attempt, clean_created_at, clean_name, to_json
from chainsim.game.server.replayer import Cancelled, OverBudget, ReplayFailed, ReplayProcess
from chainsim.game.study import protocol, register
from chainsim.systems.engine import limits
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.haptics import DEVICE_DETAILS, DEVICE_MEASURES
from chainsim.systems.procedures import procedure_for

logger = logging.getLogger(__name__)

#: replays run at once (one process each); the rest wait in the database
DEFAULT_WORKERS = 2
#: a claim older than this (seconds) is taken over: its worker is presumed gone
DEFAULT_LEASE_S = 300.0
#: how often an idle worker looks for new uploads (seconds); a new upload also wakes one at once
POLL_S = 1.0
#: claims of one upload before it is refused: the first, and one more after its scorer died or its replay
#: process failed (a recording that kills every process it runs in must not hold a scorer for ever)
MAX_CLAIMS = 2
#: claimed uploads a scorer looks at for a lapsed claim, oldest first
CLAIMS_LOOKED_AT = 200
#: settings a recording may carry; a replay uses only the deformation model
RECORDING_SETTINGS = ("class", "trainee", "model")
#: the longest session (simulated seconds) this server replays, unless ``serve --max-session-minutes`` says
#: otherwise: a class's session is rarely over half an hour, and a longer recording is refused in one line
DEFAULT_MAX_SESSION_S = 45 * 60.0
#: a replay's time budget (seconds of wall time): this much to start (a process on a cold cache compiles its
#: kernels first, minutes on a busy 2-core machine), then twice the session's own simulated time (a replay
#: slower than that is killed; replays run many times faster, prp's held cheek tissue about as fast)
BUDGET_START_S = 600.0
BUDGET_PER_SIM_S = 2.0

#: where the replay's and the simulator's figures may differ without a flag: times by a frame or two
#: (a window that took several steps in one frame saves a step or two later than the replay), the
#: dose with them, everything else by rounding only
TIME_TOLERANCE_S = 0.1
COMPARED = (*LEGACY_METRICS, "target")  # every fixed figure of an attempt
#: what a replay process runs
REPLAY_TARGET = "chainsim.game.server.scoring:replay_record"


# -- the server's packs --------------------------------------------------------------------------


class ServerPacks:
    """The packs this server scores with: by name only (an upload never names a folder).

    A pack's identity is cached with the names, sizes and modification times of its files (and of the
    packs it requires); each lookup compares them again, so a trainer who updates a pack on a running
    server has uploads made with the new files accepted at once, and the old files' uploads refused,
    without a restart. The comparison reads no file contents: only a changed pack is read and hashed."""

    def __init__(self, pack_paths: list[str] | tuple = ()) -> None:
        self.pack_paths = list(pack_paths)
        self._cache: dict[str, tuple[tuple, dict]] = {}
        self._lock = threading.Lock()

    def info(self, name: str) -> dict | None:
        """``{"root", "identity", "scenes"}`` of the pack called ``name``, or None when there is none."""
        # one lookup at a time: the first uploads after a start all want the same pack, and loading and
        # hashing it once per waiting upload (a thundering herd) held each of them for seconds
        with self._lock:
            cached = self._cache.get(name)
            if cached is not None and cached[0] == _signature(cached[1]["roots"]):
                return cached[1]
            info = self._load(name)
            if info is None:
                self._cache.pop(name, None)
            else:
                self._cache[name] = (_signature(info["roots"]), info)
            return info

    def _load(self, name: str) -> dict | None:
        from chainsim.game.packs import pack as packs  # noqa: PLC0415 - loaded when the first upload needs it
        from chainsim.game.packs.discovery import discover  # noqa: PLC0415

        found: dict[str, Path] = {}
        for f in discover(self.pack_paths):
            found.setdefault(f.name, f.path)
        if name not in found:
            return None
        pack = packs.load(found[name], self.pack_paths)
        info = {
            "root": str(found[name]),
            "roots": [str(found[name])] + [str(p) for _, p in sorted(pack.deps.items())],
            "identity": provenance.pack_identity(pack),
            "scenes": pack.scene_names(),
            "default_scene": pack.manifest["pack"].get("default_scene"),
        }
        return info


def _signature(roots: list[str]) -> tuple:
    """Names, sizes and modification times of every file of ``roots``: what a pack's update changes."""
    return provenance.files_listing([Path(r) for r in roots])


# -- checking an upload (on the request) ---------------------------------------------------------


def _recording_fields(rec: dict) -> dict:
    """The fields a replay needs, checked; UserError naming the first bad one."""
    for key in ("pack", "scene", "digest"):
        v = rec.get(key)
        if not isinstance(v, str) or not v or len(v) > limits.MAX_PATH_LENGTH:
            raise UserError(f"recording field '{key}' missing or not text")
    try:
        steps = limits.whole(rec.get("steps"), 1, limits.MAX_STEPS)
        dt = limits.number(rec.get("dt"), limits.MIN_DT, limits.MAX_DT)
    except limits.LimitError as e:
        raise UserError(f"recording field 'steps' or 'dt': {e} (docs/limits.md)") from None
    settings = rec.get("settings") or {}
    if not isinstance(settings, dict) or any(
        k not in RECORDING_SETTINGS or not isinstance(v, str) for k, v in settings.items()
    ):
        raise UserError(f"recording 'settings' may hold only text values of {', '.join(RECORDING_SETTINGS)}")
    return {"scene": rec["scene"], "steps": steps, "dt": dt, "model": settings.get("model")}


def check_upload(packs: ServerPacks, body: dict) -> dict:
    """Take the evidence out of an upload and check its envelope; UserError (a 422) naming what is wrong.

    The recording is not read here: inflating and parsing it is the scorer's work, in its own process
    (a small upload can hold a large recording; the request thread must stay cheap). Returns ``claimed``
    (the simulator's figures, cleaned), ``recording`` (the compressed text, as kept) and ``identity``."""
    text = body.pop("recording", None)
    identity = body.pop("pack_identity", None)
    if text is None or identity is None:
        raise UserError(
            "an attempt must carry its recording and pack_identity: the server scores it by replaying it "
            "(save from chainsim play/run with --records; a current simulator sends both)"
        )
    identity = provenance.clean_identity(identity)
    claimed = clean_attempt(body)
    if claimed["pack"] != identity["name"]:
        raise UserError(f"attempt pack {claimed['pack']!r} is not pack_identity.name {identity['name']!r}")
    info = packs.info(identity["name"])
    if info is None:
        raise UserError(f"pack {identity['name']!r} is not on this server; ask the trainer to install it")
    have = info["identity"]
    if (have["version"], have["hash"]) != (identity["version"], identity["hash"]):
        raise UserError(
            f"pack {identity['name']!r} version {identity['version']} (files {identity['hash'][:12]}) is not the "
            f"server's (version {have['version']}, files {have['hash'][:12]}); the attempt was made on another copy "
            "of the pack, so the server cannot score it"
        )
    provenance.check_recording_text(text)
    return {"claimed": claimed, "recording": text, "identity": identity}


def body_hash(body: dict) -> str:
    """A fingerprint of an upload's body, so a reused Idempotency-Key with another body is noticed."""
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


# -- replaying (in a worker process) -------------------------------------------------------------


def replay_record(
    recording_text: str, pack_root: str, pack_paths: list[str], options: dict | None = None, report=None
) -> dict:
    """Replay a recording headless on the pack at ``pack_root``, up to the Save that made the upload.

    ``options``: ``witnessed`` (the browser trainer's own recording: its form is the server's, not checked)
    and ``max_session_s`` (the longest session this server replays). ``report``, when given, is told the
    session's simulated time once the recording is read (the scorer sets the replay's budget from it).
    Returns ``{"record", "flags", "digest_ok", "sim_s", "steps"}``: the attempt record the Save made, why
    its input is beyond a person's (``chainsim.game.records.plausible``), whether the replay's state at
    the Save is the simulator's (``components.digest``), and the steps replayed of the recording's.
    Raises UserError when the recording is not the window's, is longer than the server replays, or
    does not replay to a Save."""
    from chainsim.components.digest import world_digest  # noqa: PLC0415 - worker process only
    from chainsim.components.resources import Records, Settings  # noqa: PLC0415
    from chainsim.game.packs import pack as packs  # noqa: PLC0415
    from chainsim.game.trainer.headless import app_for_pack, check_events  # noqa: PLC0415
    from chainsim.game.trainer.inputscript import parse_events  # noqa: PLC0415

    opts = options or {}
    recording = provenance.decode_recording(recording_text)
    fields = _recording_fields(recording)
    pack = packs.load(Path(pack_root), pack_paths)
    trial = opts.get("protocol")  # a study's trial, as the server's register gives it (enqueue)
    if not opts.get("witnessed"):
        _window_form(recording, pack, trial)
    sim_s = fields["steps"] * fields["dt"]
    cap = float(opts.get("max_session_s", DEFAULT_MAX_SESSION_S))
    if sim_s > cap:
        raise UserError(
            f"the recording is a {sim_s / 60:.1f}-minute session; this server replays sessions of up to "
            f"{cap / 60:g} minutes (serve --max-session-minutes)"
        )
    if report is not None:
        report({"sim_s": sim_s})
    events = parse_events(recording, "recording")
    settings = {"model": fields["model"]} if fields["model"] else {}
    app = app_for_pack(pack, fields["scene"], settings=settings, dt=fields["dt"], save="scoring replay")
    if trial:  # the replayed Save keeps the trial in its details, as the session's did
        app.resource(Settings).values["protocol"] = dict(trial)
    try:
        saved: list[tuple[dict, str]] = []

        def capture(class_name: str, trainee: str, record: dict) -> int:
            # the simulator took its digest at this same point of the Save (game.trainer.headless.attempt_evidence)
            saved.append((record, world_digest(app)))
            return len(saved)

        # the procedure saves through Records; here each save is caught instead of stored
        app.insert_resource(Records(save_attempt=capture, list_attempts=lambda c, t: [], where="replay"))
        check_events(app, events, "recording")
        locks = protocol.aid_locks(recording["event"]) if trial else []
        steps_run = _step_to_save(app, events, fields["steps"], saved, locks)
    finally:
        app.close()
    if not saved:
        raise UserError("the recording does not replay to a saved attempt (the replayed session never saved)")
    record, digest = saved[-1]
    if trial:
        protocol.check_replayed_aids(record, trial)
    minimum = float(pack.section("records").get("min_attempt_s", 0.0))
    flags = [] if opts.get("witnessed") else plausible.flags(recording["event"], record.get("duration_s"), minimum)
    return {
        "record": record,
        "flags": flags,
        "digest_ok": digest == recording["digest"],
        "sim_s": sim_s,
        "steps": (steps_run, fields["steps"]),
        "device_metrics": [
            name for name, spec in pack.section("metrics").items() if spec.get("measure") in DEVICE_MEASURES
        ],
    }


def _step_to_save(app: Any, events: list, steps: int, saved: list, locks: list[tuple[float, float]]) -> int:
    """Step the replay through ``events`` until the upload's Save (its last input) has saved, or ``steps``;
    the steps run. ``locks``: when a study session held the aids locked (``protocol.aid_locks``)."""
    from chainsim.components.resources import PendingInput  # noqa: PLC0415 - worker process only

    pending = app.resource(PendingInput)
    pending.extend(events)
    for n in range(1, steps + 1):
        if locks:
            protocol.hold_locks(app, locks)
        app.update(app.time.dt)
        if saved and pending.exhausted:  # the upload's Save is the recording's last input: stop there
            return n
    return steps


def _window_form(recording: dict, pack: Any, trial: dict | None) -> None:
    """UserError unless the recording is the window's (``plausible.window_form``); a study's trial may also
    hold the aids and points its session set, and nothing else of their kind (``protocol``)."""
    plausible.window_form(
        recording, float(pack.section("settings").get("dt", 1.0 / 120.0)), protocol.SESSION_KINDS if trial else ()
    )
    if trial:
        protocol.check_session_events(recording, trial, pack)


def device_reported(claimed: dict, record: dict, device_metrics: list[str]) -> list[str]:
    """Take the device's figures from the simulator's claim into the replay's `record`; the fields taken.

    An attempt made with a force-feedback device records the depths the hand gave, not the hand: the
    forces it felt were measured on the trainee's machine and a replay cannot feel them again (it gives
    no value). They are kept as the simulator reported them, where the replay has none, and named in
    ``details.reported_by_device`` so the attempt page says so. Every other figure stays the replay's."""
    said = claimed.get("details") or {}
    if not said.get("device"):
        return []
    details, metrics, taken = record.setdefault("details", {}), record.setdefault("metrics", {}), []
    for k in DEVICE_DETAILS:
        if details.get(k) is None and said.get(k) is not None:
            details[k] = said[k]
            taken.append(k)
    for name in device_metrics:
        value = (claimed.get("metrics") or {}).get(name)
        if metrics.get(name) is None and value is not None:
            metrics[name] = value
            taken.append(f"metrics.{name}")
    if taken:
        details["reported_by_device"] = taken
    return taken


def _close(a: Any, b: Any, *, name: str) -> bool:
    if isinstance(a, str) or isinstance(b, str) or a is None or b is None:
        return a == b
    a, b = float(a), float(b)
    if name.endswith("_s") or name.startswith("step_times."):
        return abs(a - b) <= TIME_TOLERANCE_S
    if name == "dose_mgy":
        return abs(a - b) <= 0.05 * max(abs(a), abs(b)) + 1e-9
    return math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-6)


def differences(claimed: dict, scored: dict) -> list[dict]:
    """``[{"field", "simulator", "replay"}]`` where the simulator's figures are not the replay's."""
    out = []
    # every figure of the attempt's procedure (the records' fixed figures unless it names another), and its target
    proc = procedure_for(claimed["procedure"]) if "procedure" in claimed else None
    figures = [c.name for c in proc.layout.columns] if proc is not None and proc.layout is not None else []
    pairs = [(k, claimed.get(k), scored.get(k)) for k in [*figures, *COMPARED]]
    for k in sorted(set(claimed.get("step_times", {})) | set(scored.get("step_times", {}))):
        pairs.append((f"step_times.{k}", claimed["step_times"].get(k), scored["step_times"].get(k)))
    for k in sorted(set(claimed.get("metrics", {})) | set(scored.get("metrics", {}))):
        pairs.append((f"metrics.{k}", claimed["metrics"].get(k), scored["metrics"].get(k)))
    for k in sorted(set(claimed.get("aids", {})) | set(scored.get("aids", {}))):
        pairs.append((f"aids.{k}", claimed["aids"].get(k), scored["aids"].get(k)))
    for name, a, b in pairs:
        if not _close(a, b, name=name):
            out.append({"field": name, "simulator": a, "replay": b})
    return out


# -- the queue -----------------------------------------------------------------------------------


def upload_for_key(store: RecordStore, key: str) -> dict | None:
    return upload_queue.read_by_key(store, key)


def enqueue(
    store: RecordStore,
    filed_by: str,
    class_name: str,
    trainee: str,
    checked: dict,
    key,
    digest: str,
    *,
    witnessed: bool = False,
):
    """Commit an upload to the queue; ``(row, created)`` - a known key returns its first row instead.

    ``witnessed``: the browser trainer's save (the server ran the session). A class that requires
    witnessed attempts refuses any other upload (UserError, a 422)."""
    if not witnessed and store.require_witnessed(class_name):
        raise UserError(
            f"class {class_name!r} takes only attempts made in the browser trainer (/train/PACK on this server), "
            "which the server witnesses; an attempt made in the window cannot be filed there"
        )
    claimed = checked["claimed"]
    if "protocol" in (claimed.get("details") or {}):
        # a study's trial: kept as the server's design and register give it, refused when they disagree
        claimed["details"]["protocol"] = register.check_trial(store, class_name, trainee, claimed)
    now = clean_created_at(None)
    with store.transaction() as conn:
        if key is not None:
            row = upload_queue.find_by_key(conn, key)
            if row is not None:
                return dict(row), False
        claimed = checked["claimed"]
        uid = upload_queue.insert(
            conn,
            key=key,
            body_hash=digest,
            filed_by=filed_by,
            class_name=class_name,
            trainee=trainee,
            received_at=now,
            identity=checked["identity"],
            claimed_json=to_json(claimed),
            recording=checked["recording"],
            witnessed=witnessed,
        )
        row = upload_queue.find(conn, uid)
    assert row is not None  # inserted above, in this transaction
    return dict(row), True


def upload_view(row: dict) -> dict:
    """What ``GET /api/uploads/ID`` and the acknowledgement say about an upload."""
    return {
        "upload": row["id"],
        "status": row["state"],
        "attempt_id": row["attempt_id"],
        "error": row["error"],
        "received_at": row["received_at"],
        "class_name": row["class_name"],
        "trainee": row["trainee"],
        "filed_by": row["filed_by"],
        "pack": row["pack"],
        "witnessed": bool(row.get("witnessed")),
    }


def attempt_number(store: RecordStore, row: dict) -> int | None:
    """The number an upload's attempt has (or will have, once scored) in its trainee's list of attempts,
    as the simulator's My attempts counts them: 1 for the first. None for a refused upload.

    Attempts come in the order the server received them and waiting uploads are scored in that order,
    so an upload still scoring comes after every attempt stored and every earlier upload still waiting;
    one statement counts both, so an upload scored meanwhile is counted once."""
    if row["state"] == "scoring":
        n = upload_queue.count_before_waiting(store, row["class_name"], row["trainee"], row["id"])
    elif row["state"] == "scored" and row["attempt_id"] is not None:
        n = upload_queue.count_up_to_attempt(store, row["class_name"], row["trainee"], row["attempt_id"])
    else:
        return None
    return n or None


def get_upload(store: RecordStore, upload_id: int) -> dict | None:
    return upload_queue.read(store, upload_id)


def waiting_uploads(store: RecordStore, classes: list[str], trainee: str | None = None) -> list[dict]:
    """Uploads of these classes not scored yet, and those refused: what the dashboard lists beside attempts."""
    if not classes:
        return []
    return upload_queue.not_scored(store, classes, trainee)


def list_queue(store: RecordStore, state: str = "waiting") -> list[dict]:
    """Uploads for ``chainsim records uploads``: ``waiting`` (not scored yet), ``refused`` or ``all``."""
    return upload_queue.listing(store, state)


def end_upload(store: RecordStore, upload_id: int, actor: str, how: str, reason: str) -> dict:
    """Cancel (``how="cancel"``: withdrawn, e.g. sent by mistake) or refuse (``how="refuse"``: not accepted)
    an upload still waiting or being scored; a replay in flight is stopped by its scorer within a second
    or so. One audit row. UserError when there is no such upload or it is already scored or refused."""
    reason = reason.strip() if isinstance(reason, str) else ""
    if not reason or len(reason) > 500:
        raise UserError("say why, in 1-500 characters (--reason)")
    verb = {"cancel": "cancelled", "refuse": "refused"}[how]
    with store.transaction() as conn:
        row = upload_queue.state_and_class(conn, upload_id)
        if row is None:
            raise UserError(f"no upload with id {upload_id}")
        if row["state"] != "scoring":
            raise UserError(f"upload {upload_id} is already {row['state']}; only a waiting upload can be {verb}")
        upload_queue.mark_refused(conn, upload_id, f"{verb} by {actor}: {reason}", clean_created_at(None))
        store.audit(conn, actor, how, row["class_name"], f"upload {upload_id}: {reason}")
    got = get_upload(store, upload_id)
    assert got is not None
    return got


def _host() -> str:
    return socket.gethostname()


def _gone(claimed_by: str | None, mine: str) -> bool:
    """True when a claim belongs to a process of this host that no longer runs (or to an earlier server
    that had this process id: its claims carry another instance token than ``mine``)."""
    if not claimed_by:
        return True
    host, pid, token = ([*claimed_by.split("|"), "", ""])[:3]
    if host != _host() or not pid.isdigit():
        return False
    if int(pid) == os.getpid():
        return not claimed_by.startswith(mine + "|")
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # alive, another user's
        return False
    return False


def _candidates(conn: Any, mine: str, lease_s: float, now: float) -> list[Any]:
    """Uploads a worker may claim now: each trainee's oldest unclaimed one, and any whose claim lapsed."""
    rows = upload_queue.waiting_heads(conn)
    for r in upload_queue.claimed_waiting(conn, CLAIMS_LOOKED_AT):
        if (r["claimed_at"] or 0) < now - lease_s or _gone(r["claimed_by"], mine):
            rows.append(r)
    return rows


def _last_served(conn: Any, rows: list[Any]) -> dict[tuple[str, str], float]:
    """When each of these rows' trainees last had an upload claimed (0: never)."""
    out: dict[tuple[str, str], float] = {}
    for r in rows:
        who = (r["class_name"], r["trainee"])
        if who not in out:
            out[who] = float(upload_queue.last_claimed_at(conn, *who) or 0.0)
    return out


def claim(store: RecordStore, worker: str, lease_s: float) -> dict | None:
    """Take the next upload for ``worker`` (``host|pid|instance|n``); None when there is none.

    Trainees are served in turn: among each trainee's oldest waiting upload, the one whose trainee was
    served longest ago goes first, so one trainee's flood of uploads delays another's by at most one
    replay. An upload already claimed ``MAX_CLAIMS`` times (its scorers died) is refused instead."""
    mine = "|".join(worker.split("|")[:3])
    now = time.time()
    with store.transaction() as conn:
        rows = _candidates(conn, mine, lease_s, now)
        served = _last_served(conn, rows)
        for r in sorted(rows, key=lambda r: (served[(r["class_name"], r["trainee"])], r["id"])):
            if r["tries"] >= MAX_CLAIMS:
                upload_queue.mark_refused(
                    conn,
                    r["id"],
                    f"scoring was started {r['tries']} times and never finished (the replay process or the "
                    "server stopped each time); send the attempt again or ask the trainer",
                    clean_created_at(None),
                )
                store.audit(conn, "server", "refuse", r["class_name"], f"upload {r['id']}: scoring never finished")
                continue
            upload_queue.mark_claimed(conn, r["id"], worker, now)
            claimed = upload_queue.find(conn, r["id"])
            assert claimed is not None  # claimed above, in this transaction
            return dict(claimed)
    return None


def renew(store: RecordStore, upload_id: int, worker: str) -> bool:
    """Renew ``worker``'s claim on a replaying upload; False when it is no longer this worker's to score
    (cancelled or refused meanwhile, or taken over)."""
    with store.transaction() as conn:
        return upload_queue.renew_claim(conn, upload_id, worker, time.time())


def finish(store: RecordStore, upload: dict, worker: str, scored: dict | None, error: str | None) -> int | None:
    """Store the replay's attempt (or the refusal) and mark the upload, in one transaction, if still claimed.

    Returns the new attempt's id (None when refused, or when the claim was lost to another worker)."""
    now = clean_created_at(None)
    with store.transaction() as conn:
        row = upload_queue.claim_of(conn, upload["id"])
        if row is None or row["state"] != "scoring" or row["claimed_by"] != worker:
            return None  # another worker took it over and finishes it; never two attempts
        if scored is None:
            assert error is not None  # a refusal always says why
            upload_queue.mark_refused(conn, upload["id"], error[:500], now)
            return None
        claimed = json.loads(upload["claimed"])
        record = clean_attempt({**scored["record"], "created_at": upload["received_at"]})
        record["pack"] = upload["pack"]
        device_reported(claimed, record, scored.get("device_metrics", []))
        diffs = differences(claimed, record)
        if not scored["digest_ok"]:
            diffs.append({"field": "state at the Save", "simulator": "recorded digest", "replay": "another"})
        flags = list(scored["flags"])
        aid = store.insert_attempt(
            conn,
            clean_name("class", upload["class_name"]),
            clean_name("trainee", upload["trainee"]),
            record,
            key=upload["idem_key"],
            provenance={
                "filed_by": upload["filed_by"],
                "client_created_at": claimed.get("created_at"),
                "pack_version": upload["pack_version"],
                "pack_hash": upload["pack_hash"],
                "client_figures": claimed,
                "differences": diffs,
                "recording": upload["recording"],
                "source": "witnessed" if upload.get("witnessed") else "replayed",
                "flags": flags,
            },
        )
        if flags:
            store.audit(
                conn, "server", "implausible", upload["class_name"], "input beyond a person's: " + "; ".join(flags), aid
            )
        if diffs:
            store.audit(
                conn,
                "server",
                "flag",
                upload["class_name"],
                "result differs from the simulator's: " + ", ".join(d["field"] for d in diffs),
                aid,
            )
        upload_queue.mark_scored(conn, upload["id"], aid, now)
        return aid


class Scorer:
    """The bounded pool that scores uploads (see module docstring); ``start`` it, ``wake`` it, ``stop`` it.

    Each of ``workers`` threads owns one replay process (``chainsim.game.server.replayer``). While it
    replays, the thread renews its claim every ``lease_s / 4`` (a live replay is never taken over),
    kills the replay when the upload is cancelled meanwhile, and kills a replay that runs past its
    budget: ``BUDGET_START_S`` plus ``BUDGET_PER_SIM_S`` times the session's simulated time."""

    def __init__(
        self,
        db: str | None,
        packs: ServerPacks,
        workers: int = DEFAULT_WORKERS,
        lease_s: float = DEFAULT_LEASE_S,
        max_session_s: float = DEFAULT_MAX_SESSION_S,
    ) -> None:
        if not 1 <= workers <= 64:
            raise UserError(f"--scorers must be from 1 to 64, got {workers}")
        if not 1.0 <= max_session_s <= 24 * 3600.0:
            raise UserError(f"--max-session-minutes must be from 1/60 to 1440, got {max_session_s / 60:g}")
        self.db = db
        self.packs = packs
        self.workers = workers
        self.lease_s = lease_s
        self.max_session_s = max_session_s
        self._stop = threading.Event()
        self._wake = threading.Condition()
        self._threads: list[threading.Thread] = []
        self._procs: list[ReplayProcess] = []
        self.prefix = f"{_host()}|{os.getpid()}|{uuid.uuid4().hex[:8]}"

    def start(self) -> None:
        for i in range(self.workers):
            proc = ReplayProcess(REPLAY_TARGET)
            self._procs.append(proc)
            t = threading.Thread(target=self._loop, args=(f"{self.prefix}|{i}", proc), name=f"scorer-{i}", daemon=True)
            t.start()
            self._threads.append(t)

    def wake(self) -> None:
        with self._wake:
            self._wake.notify()

    def stop(self) -> None:
        self._stop.set()
        with self._wake:
            self._wake.notify_all()
        for proc in self._procs:  # a replay in flight ends now; its upload is claimed again after a restart
            proc.close()
        for t in self._threads:
            t.join(timeout=30)

    def _loop(self, worker: str, proc: ReplayProcess) -> None:
        store = None
        gone: tuple[type[BaseException], ...] = (UserError, *db_errors())  # the database gone or busy
        while not self._stop.is_set():
            try:
                if store is None:
                    store = RecordStore(self.db)
                upload = claim(store, worker, self.lease_s)
                if upload is None:
                    with self._wake:
                        self._wake.wait(POLL_S)
                    continue
                self._score(store, upload, worker, proc)
            except gone as exc:  # reconnect and try again
                logger.warning("scoring: %s", exc)
                if store is not None:
                    try:
                        store.close()
                    except Exception:  # the connection is already broken
                        logger.debug("closing a failed scoring connection", exc_info=True)
                store = None
                self._stop.wait(POLL_S)
            except Exception:  # a scorer that died would stall every class's scoring: say it and go on
                logger.exception("scoring: an unexpected error; this scorer goes on with the next upload")
                self._stop.wait(POLL_S)
        proc.close()
        if store is not None:
            store.close()

    def _replay(
        self, store: RecordStore, upload: dict, worker: str, proc: ReplayProcess, root: str
    ) -> tuple[dict | None, str | None] | None:
        """Run the upload's replay in ``proc``, renewing the claim; ``(scored, error)``, or None to drop it
        (cancelled, taken over, or the server stopping)."""
        # until the replay has read the recording's length
        budget = [BUDGET_START_S + BUDGET_PER_SIM_S * self.max_session_s]
        renewed = [time.monotonic()]

        def keep_going() -> bool:
            if self._stop.is_set():
                return False
            if time.monotonic() - renewed[0] >= self.lease_s / 4:
                renewed[0] = time.monotonic()
                return renew(store, upload["id"], worker)
            return True

        def on_note(note: dict) -> float:
            budget[0] = BUDGET_START_S + BUDGET_PER_SIM_S * float(note.get("sim_s", self.max_session_s))
            return budget[0]

        options = {"witnessed": bool(upload.get("witnessed")), "max_session_s": self.max_session_s}
        trial = (json.loads(upload["claimed"]).get("details") or {}).get("protocol")
        if trial:
            options["protocol"] = trial
        try:
            job = (upload["recording"], root, self.packs.pack_paths, options)
            answer = proc.run(job, budget[0], keep_going, on_note)
        except Cancelled:
            logger.info("upload %s: replay stopped (cancelled, taken over or server stopping)", upload["id"])
            return None
        except OverBudget:
            return None, (
                f"the replay ran past its budget of {budget[0]:.0f} s ({BUDGET_START_S:.0f} s to start and "
                f"{BUDGET_PER_SIM_S:g} s for each second of the session) and was stopped"
            )
        except ReplayFailed as exc:
            if self._stop.is_set():
                return None
            logger.warning("scoring upload %s: %s; it is tried again once", upload["id"], exc)
            with store.transaction() as conn:  # free the claim for the next try (claims are counted)
                upload_queue.release_claim(conn, upload["id"])
            return None
        if answer[0] == "ok":
            return answer[1], None
        if answer[1] == "UserError":
            return None, f"the recording does not replay: {answer[2]}"
        logger.warning("scoring upload %s failed: %s: %s", upload["id"], answer[1], answer[2])
        return None, f"the recording does not replay: {answer[1]}: {answer[2][:200]}"

    def _score(self, store: RecordStore, upload: dict, worker: str, proc: ReplayProcess) -> None:
        info = self.packs.info(upload["pack"])
        if info is None or info["identity"]["hash"] != upload["pack_hash"]:
            scored = None
            error = f"pack {upload['pack']!r} is no longer on this server at the version the attempt ran on"
        elif upload.get("witnessed"):
            # the browser trainer's session ran in this server's own process, driven only by the trainee's
            # checked device events: its figures are the server's already, and replaying them proves nothing new
            record = json.loads(upload["claimed"])
            scored, error = {"record": record, "flags": [], "digest_ok": True, "sim_s": 0.0, "steps": (0, 0)}, None
        else:
            result = self._replay(store, upload, worker, proc, info["root"])
            if result is None:
                return
            scored, error = result
        aid = finish(store, upload, worker, scored, error)
        if aid is not None:
            assert scored is not None
            run, of = scored["steps"]
            if upload.get("witnessed"):
                logger.info("upload %s stored: attempt %s (witnessed: the server ran the session)", upload["id"], aid)
                return
            logger.info(
                "upload %s scored: attempt %s (replayed %d of the recording's %d steps)", upload["id"], aid, run, of
            )
        elif error:
            logger.info("upload %s refused: %s", upload["id"], error)

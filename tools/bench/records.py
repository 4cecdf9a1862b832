"""`chainsim bench records`: real uploads to a local records server, scored by replay; speed and a count check.

The bench works on a copy of the built-in rhizotomy pack in its temporary folder, served with
``--pack-path``: a pack edited while the bench runs would otherwise be hashed again by the server
and the bench's uploads, made with the old files, refused as another copy of the pack.

First the bench makes one real upload as the simulator does: the copied rhizotomy pack runs its
correct attempt headless as a person makes it at the window (clicks and drags at a person's pace,
``chainsim.game.trainer.windowform``; with ``--session-minutes M`` spread over an M-minute session with
the pointer moving between gestures) and clicks Save, and the upload the simulator queues (its
figures, the compressed recording, the pack's identity) is taken from its local outbox. It times
replaying that recording the way the server scores it, pinned to one core: the replay speed is
replay seconds per simulated second (below 0.1 is "10x real time or faster").

Then it starts ``chainsim serve`` on 127.0.0.1 over the given database (a fresh SQLite file in a
temporary folder by default, or a postgresql:// URL of a scratch database) with ``--scorers N``
replay workers, makes one trainee account and API token per client in a class of its own, and lets
``--clients`` threads each send ``--attempts`` uploads through the JSON API (keep-alive
connections, an idempotency key each). Acknowledgement is the time from sending an upload to its
202; scoring is the time from the 202 to the server having stored the replay's attempt (the bench
watches the uploads table every 0.2 s). The count check: every acknowledged upload scored, once,
into one attempt, and nothing refused. ``last_save_to_last_scored_s`` is what a class waits at the end
of a session when every trainee saves at once: from the last acknowledgement to the last result.
The bench class, its accounts, uploads and attempts are removed at the end (``--keep`` leaves
them), and the server is stopped.
"""

from __future__ import annotations

import http.client
import json
import os
import secrets
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from chainsim.systems.engine.errors import UserError

HELP = "real uploads to a local records server: replay speed, acknowledgement and scoring p50/p99, count check"
PASSWORD = "bench-" + "x" * 12
#: how often the bench looks for newly scored uploads (seconds): the resolution of the scoring times
POLL_S = 0.2
#: the scripted attempt every bench upload carries
SCRIPT = "correct.toml"


def add_arguments(p) -> None:
    p.add_argument("--clients", type=int, default=50, help="trainees uploading at once (default 50)")
    p.add_argument("--attempts", type=int, default=20, help="uploads per trainee (default 20)")
    p.add_argument("--scorers", type=int, default=2, help="the server's replay workers (serve --scorers, default 2)")
    p.add_argument("--db", metavar="PATH|URL", help="records database (default: a new SQLite file in a temp folder)")
    p.add_argument("--timeout", type=float, default=3600.0, help="longest wait for the scoring, seconds (default 3600)")
    p.add_argument("--keep", action="store_true", help="keep the bench class, its accounts, uploads and attempts")
    p.add_argument(
        "--session-minutes",
        type=float,
        default=0.0,
        metavar="M",
        help="each upload is a session of M minutes at the window (the attempt's gestures spread out, the "
        "pointer moving between them); default: the attempt alone, about 16 s",
    )
    p.add_argument(
        "--tissue",
        choices=("with", "without"),
        default="with",
        help="the prp pack as shipped, with its cheek tissue (default), or without it",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")


# -- one real upload, and how fast it replays -----------------------------------------------------


def copy_pack(folder: Path, tissue: bool = True) -> list[str]:
    """The built-in prp pack copied into ``folder/packs`` (without its soft tissue when ``tissue`` is false,
    as ``chainsim bench replay`` cuts it); the pack paths that find the copy first."""
    from chainsim.game.packs.discovery import BUILTIN_DIR  # noqa: PLC0415
    from chainsim.tools.bench.replay import without_tissue  # noqa: PLC0415

    source = BUILTIN_DIR / "prp"
    if not (source / "pack.toml").is_file():
        raise UserError("the built-in pack 'prp' is missing; reinstall chainsim")
    shutil.copytree(source, folder / "packs" / "prp", ignore=shutil.ignore_patterns("__pycache__", ".*"))
    if not tissue:
        manifest = folder / "packs" / "prp" / "pack.toml"
        manifest.write_text(without_tissue(manifest.read_text(encoding="utf-8")), encoding="utf-8")
    return [str(folder / "packs")]


def _stretched(events: list, minutes: float) -> list:
    """The gestures spread over a session of ``minutes``, as a person takes them: idle time between, and the
    pointer travelling to each target over the second before it (30 moves a second)."""
    from chainsim.components.input_events import MouseButton, MouseMove  # noqa: PLC0415

    presses = [i for i, (_, ev) in enumerate(events) if isinstance(ev, MouseButton) and ev.pressed]
    if minutes <= 0 or len(presses) < 2:
        return events
    span = events[-1][0]
    extra = max(0.0, minutes * 60.0 - span) / len(presses)  # the same pause before every click
    out, shift, last = [], 0.0, (640.0, 400.0)
    for i, (t, ev) in enumerate(events):
        nxt = events[i + 1][1] if i + 1 < len(events) else None
        if extra >= 1.5 and isinstance(nxt, MouseButton) and nxt.pressed:
            shift += extra
            x, y = ev.x, ev.y
            for k in range(30):  # the hand on its way to the target
                f = (k + 1) / 31
                out.append(
                    (
                        t + shift - 1.0 + k / 30,
                        MouseMove(round(last[0] + f * (x - last[0])), round(last[1] + f * (y - last[1]))),
                    )
                )
            last = (x, y)
        out.append((t + shift, ev))
    return out


def make_upload(folder: Path, pack_paths: list[str], session_minutes: float = 0.0) -> dict:
    """The upload the simulator queues after the prp pack's correct attempt made at the window at a person's
    pace (``chainsim.game.trainer.windowform``), over a session of ``session_minutes`` when given, and a Save."""
    from chainsim.components.resources import PendingInput  # noqa: PLC0415 - the simulator, loaded when used
    from chainsim.game.records import remote  # noqa: PLC0415
    from chainsim.game.records.store import RecordStore  # noqa: PLC0415
    from chainsim.game.server.scoring import ServerPacks  # noqa: PLC0415
    from chainsim.game.trainer import windowform  # noqa: PLC0415
    from chainsim.game.trainer.headless import build_app  # noqa: PLC0415
    from chainsim.game.trainer.inputscript import load_script  # noqa: PLC0415

    info = ServerPacks(pack_paths).info("prp")
    if info is None:
        raise UserError("the built-in pack 'prp' is missing; reinstall chainsim")
    local = str(folder / "simulator.sqlite3")
    # nobody is signed in to this address, so the save stays in the local outbox without a request
    settings = {"db": local, "records": "http://127.0.0.1:9", "class": "bench", "trainee": "bench"}
    app = build_app("prp", pack_paths=pack_paths, settings=settings)
    try:
        events = windowform.gestures(app, load_script(Path(info["root"]) / "scripts" / SCRIPT))
        events = _stretched(events + windowform.save_click(app, events[-1][0]), session_minutes)
        app.resource(PendingInput).extend(events)
        app.run_steps(int((events[-1][0] + 1.0) * 120))
    finally:
        app.close()
    with RecordStore(local) as store:
        queued = remote.outbox_attempts(store)
    if not queued:
        raise UserError(f"the attempt made from {SCRIPT} did not save; the bench has no upload to send")
    return json.loads(queued[0])


def replay_speed(upload: dict, pack_paths: list[str], runs: int = 3) -> dict[str, Any]:
    """Time the server's replay of ``upload`` on one core: the median of ``runs`` after a warm-up.

    Both the wall-clock time and the CPU time of this process are kept: on a machine shared with
    other work the wall clock counts the time the core spent on others, the CPU time does not."""
    from chainsim.game.records import provenance  # noqa: PLC0415
    from chainsim.game.server.scoring import ServerPacks, replay_record  # noqa: PLC0415

    info = ServerPacks(pack_paths).info("prp")
    if info is None:
        raise UserError("the built-in pack 'prp' is missing; reinstall chainsim")
    recording = provenance.decode_recording(upload["recording"])
    simulated = recording["steps"] * recording["dt"]
    before = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    pinned = before is not None
    if before is not None:  # one core, as one scorer gets when every scorer is busy
        os.sched_setaffinity(0, {min(before)})
    try:
        replay_record(upload["recording"], info["root"], pack_paths)  # warm-up: kernels loaded, caches filled
        times, cpu = [], []
        for _ in range(runs):
            t0, c0 = time.perf_counter(), time.process_time()
            replay_record(upload["recording"], info["root"], pack_paths)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
    finally:
        if before is not None:
            os.sched_setaffinity(0, before)
    replay_s = statistics.median(times)
    cpu_s = statistics.median(cpu)
    return {
        "simulated_s": round(simulated, 3),
        "replay_s": round(replay_s, 3),
        "replay_s_per_simulated_s": round(replay_s / simulated, 4),
        "times_real_time": round(simulated / replay_s, 1),
        "replay_cpu_s": round(cpu_s, 3),
        "simulated_s_per_cpu_s": round(simulated / cpu_s, 1),
        "one_core": pinned,
    }


# -- the load ------------------------------------------------------------------------------------


def _free_port() -> int:
    import socket  # noqa: PLC0415 - only the bench picks ports

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start_server(db: str, log: Path, scorers: int, pack_paths: list[str]) -> tuple[subprocess.Popen, int]:
    port = _free_port()
    with log.open("ab") as fh:
        proc = subprocess.Popen(
            [sys.executable, "-m", "chainsim.game", "-q", "serve", "--db", db, "--port", str(port)]
            + ["--scorers", str(scorers), "--uploads-per-minute", "10000"]
            + [arg for p in pack_paths for arg in ("--pack-path", p)],
            stdout=fh,
            stderr=subprocess.STDOUT,
        )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise UserError(f"chainsim serve exited with {proc.returncode}: {log.read_text().strip()[-300:]}")
        try:
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=2)
            conn.request("GET", "/api/health")
            if conn.getresponse().status == 200:
                conn.close()
                return proc, port
        except OSError:
            time.sleep(0.1)
    proc.kill()
    raise UserError("chainsim serve did not answer within 60 s")


def _client(port: int, token: str, body: bytes, attempts: int, out: dict[str, Any], lock: threading.Lock) -> None:
    """Send ``attempts`` uploads one after another; note each acknowledgement's latency and time."""
    latencies: list[float] = []
    acked: dict[int, float] = {}
    errors: list[str] = []
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
    for _ in range(attempts):
        headers = {
            "Content-Type": "application/json",
            "Authorization": f"Bearer {token}",
            "Idempotency-Key": secrets.token_hex(16),
        }
        t0 = time.perf_counter()
        try:
            conn.request("POST", "/api/attempts", body, headers)
            resp = conn.getresponse()
            raw = resp.read()
            status = resp.status
        except (OSError, http.client.HTTPException) as exc:
            status, raw = 0, str(exc).encode()
            conn.close()
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=60)
        latencies.append(time.perf_counter() - t0)
        if status == 202:
            acked[int(json.loads(raw)["upload"])] = time.monotonic()
        else:
            errors.append(f"{status}: {raw[:200].decode('utf-8', 'replace')}")
    conn.close()
    with lock:
        out["latencies"].extend(latencies)
        out["acked"].update(acked)
        out["errors"].extend(errors)


def _percentile(values: list[float], q: float) -> float | None:
    if not values:
        return None
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q * (len(ordered) - 1))))]


def _ms(value: float | None) -> float | None:
    return None if value is None else round(1000 * value, 1)


def _s(value: float | None) -> float | None:
    return None if value is None else round(value, 2)


def _watch_scoring(db: str, class_name: str, acked: dict[int, float], timeout: float) -> dict[int, float]:
    """Monotonic time each acknowledged upload was first seen no longer scoring (until all are, or timeout)."""
    from chainsim.game.records import upload_queue  # noqa: PLC0415
    from chainsim.game.records.store import RecordStore  # noqa: PLC0415

    done: dict[int, float] = {}
    deadline = time.monotonic() + timeout
    with RecordStore(db) as store:
        while len(done) < len(acked) and time.monotonic() < deadline:
            ids = upload_queue.ids_done(store, class_name)
            now = time.monotonic()
            for uid in ids:
                done.setdefault(uid, now)
            if len(done) < len(acked):
                time.sleep(POLL_S)
    return done


def _check_sizes(clients: int, attempts: int, scorers: int, timeout: float, session_minutes: float) -> None:
    if not 1 <= clients <= 500:
        raise UserError(f"--clients must be 1-500, got {clients}")
    if not 1 <= attempts <= 1000:
        raise UserError(f"--attempts must be 1-1000, got {attempts}")
    if not 1 <= scorers <= 64:
        raise UserError(f"--scorers must be 1-64, got {scorers}")
    if not 1 <= timeout <= 86400:
        raise UserError(f"--timeout must be 1-86400 seconds, got {timeout}")
    if not 0 <= session_minutes <= 45:
        raise UserError(f"--session-minutes must be 0-45 (the server's longest session), got {session_minutes}")


def run_bench(
    db: str | None,
    clients: int,
    attempts: int,
    scorers: int = 2,
    keep: bool = False,
    timeout: float = 3600.0,
    session_minutes: float = 0.0,
    tissue: bool = True,
) -> dict[str, Any]:
    from chainsim.game.records import accounts, class_removal, listings, upload_queue  # noqa: PLC0415
    from chainsim.game.records.backend import is_postgres  # noqa: PLC0415 - keep `chainsim bench -h` light
    from chainsim.game.records.store import RecordStore  # noqa: PLC0415

    _check_sizes(clients, attempts, scorers, timeout, session_minutes)
    tmp = tempfile.TemporaryDirectory(prefix="chainsim-bench-")
    folder = Path(tmp.name)
    pack_paths = copy_pack(folder, tissue)
    upload = make_upload(folder, pack_paths, session_minutes)
    speed = replay_speed(upload, pack_paths)
    body = json.dumps(upload).encode()
    db = db or str(folder / "bench.sqlite3")
    class_name = f"bench-{secrets.token_hex(4)}"
    with RecordStore(db) as store:
        backend = "postgresql" if is_postgres(db) else "sqlite"
        where = str(store.path)
        tokens = []
        for n in range(clients):
            user = accounts.add_user(store, f"{class_name}-{n:03d}", "trainee", PASSWORD, [class_name])
            tokens.append(accounts.issue_token(store, user, "bench", 3600)[0])
    proc, port = _start_server(db, folder / "serve.log", scorers, pack_paths)
    out: dict[str, Any] = {"latencies": [], "acked": {}, "errors": []}
    lock = threading.Lock()
    try:
        t0 = time.monotonic()
        threads = [threading.Thread(target=_client, args=(port, tok, body, attempts, out, lock)) for tok in tokens]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        sent_s = time.monotonic() - t0
        last_ack = time.monotonic()  # the last Save: every upload is acknowledged by now
        done = _watch_scoring(db, class_name, out["acked"], timeout)
        scored_s = time.monotonic() - t0
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
    with RecordStore(db) as store:
        rows = upload_queue.outcomes(store, class_name)
        stored = listings.class_attempt_count(store, class_name)
        if not keep:
            with store.transaction() as conn:
                class_removal.delete_uploads(conn, class_name)
                class_removal.delete_users_named_like(conn, f"{class_name}-%")
                class_removal.delete_class(conn, class_name)
    tmp.cleanup()
    scored = [r for r in rows if r["state"] == "scored"]
    refused = [r for r in rows if r["state"] == "refused"]
    attempt_ids = {r["attempt_id"] for r in scored}
    acked = out["acked"]
    scoring = [done[u] - acked[u] for u in acked if u in done]
    lat = out["latencies"]
    return {
        "backend": backend,
        "database": where,
        "clients": clients,
        "attempts_per_client": attempts,
        "scorers": scorers,
        "replay": speed,
        "sent_s": round(sent_s, 2),
        "scored_s": round(scored_s, 2),
        "acknowledged": len(acked),
        "ack_p50_ms": _ms(_percentile(lat, 0.50)),
        "ack_p99_ms": _ms(_percentile(lat, 0.99)),
        "ack_max_ms": _ms(max(lat) if lat else None),
        "scoring_p50_s": _s(_percentile(scoring, 0.50)),
        "scoring_p99_s": _s(_percentile(scoring, 0.99)),
        "scoring_max_s": None if not scoring else round(max(scoring), 2),
        "scored_per_s": round(len(scored) / scored_s, 2) if scored_s else None,
        "session_minutes": session_minutes,
        "tissue": tissue,
        # what a class waits for at the end of a session: from the last Save to the last result
        "last_save_to_last_scored_s": round(max(done.values()) - last_ack, 2) if done else None,
        "errors": len(out["errors"]),
        "first_error": out["errors"][0] if out["errors"] else None,
        "scored": len(scored),
        "refused": len(refused),
        "first_refusal": refused[0]["error"] if refused else None,
        "stored": stored,
        "count_ok": len(scored) == len(acked) == len(attempt_ids) == stored and len(rows) == len(acked),
    }


def run(args) -> int:
    result = run_bench(
        args.db,
        args.clients,
        args.attempts,
        args.scorers,
        args.keep,
        args.timeout,
        args.session_minutes,
        args.tissue == "with",
    )
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        r = result["replay"]
        print(
            f"replay of one attempt ({r['simulated_s']} s simulated) on "
            f"{'one core' if r['one_core'] else 'this machine'}: {r['replay_s']} s, "
            f"{r['replay_s_per_simulated_s']} s per simulated s ({r['times_real_time']}x real time); "
            f"CPU {r['replay_cpu_s']} s: {r['simulated_s_per_cpu_s']} simulated s per CPU s\n"
            f"records server on {result['backend']} ({result['database']}): {result['clients']} trainees x "
            f"{result['attempts_per_client']} uploads, {result['scorers']} scorers\n"
            f"  acknowledged  {result['acknowledged']} in {result['sent_s']} s: p50 {result['ack_p50_ms']} ms, "
            f"p99 {result['ack_p99_ms']} ms, max {result['ack_max_ms']} ms\n"
            f"  scored        {result['scored']} by {result['scored_s']} s ({result['scored_per_s']}/s): "
            f"p50 {result['scoring_p50_s']} s, p99 {result['scoring_p99_s']} s, max {result['scoring_max_s']} s "
            "after the acknowledgement\n"
            f"  errors        {result['errors']}"
            + (f" (first: {result['first_error']})" if result["errors"] else "")
            + f", refused {result['refused']}"
            + (f" (first: {result['first_refusal']})" if result["refused"] else "")
            + "\n"
            f"  class waits   {result['last_save_to_last_scored_s']} s from the last Save to the last result "
            f"(sessions of {result['session_minutes'] or 'about 0.3'} minutes, "
            f"{'with' if result['tissue'] else 'without'} tissue)\n"
            f"  count check   {result['stored']} attempts stored, {result['scored']} uploads scored for "
            f"{result['acknowledged']} acknowledged: " + ("ok" if result["count_ok"] else "MISMATCH")
        )
    if not result["count_ok"]:
        raise UserError(
            f"count check failed: {result['acknowledged']} acknowledged, {result['scored']} scored, "
            f"{result['stored']} stored, {result['refused']} refused"
        )
    return 0

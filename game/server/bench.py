"""`chainsim bench records`: load on a local records server, then a check that nothing was lost.

Starts ``chainsim serve`` on 127.0.0.1 over the given database (a fresh SQLite file in a
temporary folder by default, or a postgresql:// URL of a scratch database), makes one trainee
account and API token per client in a class of its own, and lets ``--clients`` threads save
attempts through the JSON API (keep-alive connections, an idempotency key each) for
``--seconds``. Reports attempts per second, latency percentiles and errors, then counts the
attempts in the database: the count must equal the acknowledged saves. The bench class, its
accounts and attempts are removed at the end (``--keep`` leaves them), and the server stopped.
"""

from __future__ import annotations

import http.client
import json
import secrets
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from chainsim.engine.errors import UserError

HELP = "load a local records server with N clients saving attempts; attempts/s, latency, errors, count check"
PASSWORD = "bench-" + "x" * 12


def add_arguments(p) -> None:
    p.add_argument("--clients", type=int, default=50, help="concurrent clients (default 50)")
    p.add_argument("--seconds", type=float, default=60.0, help="how long they save (default 60)")
    p.add_argument("--db", metavar="PATH|URL", help="records database (default: a new SQLite file in a temp folder)")
    p.add_argument("--keep", action="store_true", help="keep the bench class, its accounts and attempts")
    p.add_argument("--json", action="store_true", help="print the result as JSON")


def _attempt(i: int) -> dict:
    return {
        "pack": "prp",
        "duration_s": 60.0 + i % 50,
        "landmark_error_mm": 2.0 + (i % 7) * 0.5,
        "needle_error_mm": 1.0 - (i % 5) * 0.5,
        "target": "foramen_ovale_left",
        "skull_contacts": i % 4,
        "path_length_mm": 55.0 + i % 10,
        "aids": {"tip_view": True, "reference_planes": i % 2 == 0},
        "step_times": {"landmarks": 25.0, "insert": 35.0 + i % 10},
        "details": {"D1": 1.5, "d1": 0.25, "side": "left"},
    }


def _free_port() -> int:
    import socket  # noqa: PLC0415 - only the bench picks ports

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start_server(db: str, log: Path) -> tuple[subprocess.Popen, int]:
    port = _free_port()
    with log.open("ab") as fh:
        proc = subprocess.Popen(
            [sys.executable, "-m", "chainsim.game", "-q", "serve", "--db", db, "--port", str(port)],
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


def _client(port: int, token: str, deadline: float, out: dict[str, Any], lock: threading.Lock) -> None:
    latencies: list[float] = []
    acked = errors = 0
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    i = 0
    while time.monotonic() < deadline:
        body = json.dumps(_attempt(i))
        headers = {
            "Content-Type": "application/json",
            "Authorization": f"Bearer {token}",
            "Idempotency-Key": secrets.token_hex(16),
        }
        t0 = time.perf_counter()
        try:
            conn.request("POST", "/api/attempts", body, headers)
            resp = conn.getresponse()
            resp.read()
            status = resp.status
        except (OSError, http.client.HTTPException):
            status = 0
            conn.close()
            conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
        latencies.append(time.perf_counter() - t0)
        if status == 201:
            acked += 1
        else:
            errors += 1
        i += 1
    conn.close()
    with lock:
        out["latencies"].extend(latencies)
        out["acked"] += acked
        out["errors"] += errors


def _percentile(values: list[float], q: float) -> float:
    if not values:
        return float("nan")
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q * (len(ordered) - 1))))]


def run_bench(db: str | None, clients: int, seconds: float, keep: bool = False) -> dict[str, Any]:
    from chainsim.game.records.backend import is_postgres  # noqa: PLC0415 - keep `chainsim bench -h` light
    from chainsim.game.records.store import RecordStore  # noqa: PLC0415
    from chainsim.game.server import accounts  # noqa: PLC0415

    if not 1 <= clients <= 500:
        raise UserError(f"--clients must be 1-500, got {clients}")
    if not 0.5 <= seconds <= 600:
        raise UserError(f"--seconds must be 0.5-600, got {seconds}")
    tmp = tempfile.TemporaryDirectory(prefix="chainsim-bench-")
    db = db or str(Path(tmp.name) / "bench.sqlite3")
    class_name = f"bench-{secrets.token_hex(4)}"
    with RecordStore(db) as store:
        backend = "postgresql" if is_postgres(db) else "sqlite"
        where = str(store.path)
        tokens = []
        for n in range(clients):
            user = accounts.add_user(store, f"{class_name}-{n:03d}", "trainee", PASSWORD, [class_name])
            tokens.append(accounts.issue_token(store, user, "bench", 3600)[0])
    proc, port = _start_server(db, Path(tmp.name) / "serve.log")
    out: dict[str, Any] = {"latencies": [], "acked": 0, "errors": 0}
    lock = threading.Lock()
    try:
        t0 = time.monotonic()
        deadline = t0 + seconds
        threads = [threading.Thread(target=_client, args=(port, tok, deadline, out, lock)) for tok in tokens]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        elapsed = time.monotonic() - t0
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
    with RecordStore(db) as store:
        stored = len(store.list_attempts(class_name))
        if not keep:
            with store.transaction() as conn:
                conn.execute("DELETE FROM users WHERE name LIKE ?", (f"{class_name}-%",))
                conn.execute("DELETE FROM classes WHERE name = ?", (class_name,))
    tmp.cleanup()
    lat = out["latencies"]
    return {
        "backend": backend,
        "database": where,
        "clients": clients,
        "seconds": round(elapsed, 2),
        "acknowledged": out["acked"],
        "attempts_per_s": round(out["acked"] / elapsed, 1),
        "p50_ms": round(1000 * _percentile(lat, 0.50), 2),
        "p95_ms": round(1000 * _percentile(lat, 0.95), 2),
        "max_ms": round(1000 * max(lat), 2) if lat else None,
        "mean_ms": round(1000 * statistics.fmean(lat), 2) if lat else None,
        "errors": out["errors"],
        "stored": stored,
        "count_ok": stored == out["acked"],
    }


def run(args) -> int:
    result = run_bench(args.db, args.clients, args.seconds, args.keep)
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(
            f"records server on {result['backend']} ({result['database']}): {result['clients']} clients, "
            f"{result['seconds']} s\n"
            f"  acknowledged  {result['acknowledged']} attempts, {result['attempts_per_s']} attempts/s\n"
            f"  latency       p50 {result['p50_ms']} ms, p95 {result['p95_ms']} ms, max {result['max_ms']} ms\n"
            f"  errors        {result['errors']}\n"
            f"  count check   {result['stored']} stored for {result['acknowledged']} acknowledged: "
            + ("ok" if result["count_ok"] else "MISMATCH")
        )
    if not result["count_ok"]:
        raise UserError(f"count check failed: {result['stored']} stored, {result['acknowledged']} acknowledged")
    return 0

"""kill -9 of the records server in the middle of a burst of saves, on SQLite and PostgreSQL.

Eight clients save attempts with idempotency keys as fast as the server answers; once enough
saves were acknowledged the server process gets SIGKILL. After a restart on the same database
every acknowledged attempt is there with its fields, and resending everything that was sent
(acknowledged or not) with the same keys adds each attempt at most once.
"""

from __future__ import annotations

import signal
import threading
import uuid

import pytest
from conftest import attempt, call, count_attempts, populate, start_server


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX SIGKILL")
def test_acknowledged_attempts_survive_kill_9(records_db, tmp_path):
    populate(records_db)
    server = start_server(records_db, tmp_path / "serve.log")
    token = call(server, "POST", "/api/login", {"name": "alice", "password": "correct horse 42"})[1]["token"]
    acked: dict[str, int] = {}  # idempotency key -> id, for answered saves
    sent: dict[str, dict] = {}  # every key a client tried, with its attempt
    lock = threading.Lock()
    enough = threading.Event()
    stop = threading.Event()
    refused: list = []

    def client(n: int) -> None:
        i = 0
        while not stop.is_set():
            key, a = uuid.uuid4().hex, attempt(n, duration_s=float(1000 * n + i))
            with lock:
                sent[key] = a
            try:
                status, answer, _ = call(server, "POST", "/api/attempts", a, token, {"Idempotency-Key": key})
            except OSError:  # the server died under this request: not acknowledged
                return
            if status != 201:
                refused.append((status, answer))
                enough.set()
                return
            with lock:
                acked[key] = answer["id"]
                if len(acked) >= 60:
                    enough.set()
            i += 1

    threads = [threading.Thread(target=client, args=(n,)) for n in range(8)]
    for t in threads:
        t.start()
    try:
        assert enough.wait(120), "the server did not acknowledge 60 saves"
        assert not refused, refused[0]
        server.proc.send_signal(signal.SIGKILL)
        assert server.proc.wait(10) == -signal.SIGKILL
    finally:
        stop.set()
        for t in threads:
            t.join(60)
        server.stop()
    with lock:
        acked_now, sent_now = dict(acked), dict(sent)

    server = start_server(records_db, tmp_path / "serve-again.log")
    try:
        for key, aid in acked_now.items():
            status, got, _ = call(server, "GET", f"/api/attempts/{aid}", token=token)
            assert status == 200, (aid, got)
            assert got["duration_s"] == sent_now[key]["duration_s"]
        stored_before_resend = count_attempts(records_db)
        assert stored_before_resend >= len(acked_now)
        for key, a in sent_now.items():
            status, answer, _ = call(server, "POST", "/api/attempts", a, token, {"Idempotency-Key": key})
            assert status in (200, 201), answer
            if key in acked_now:
                assert (status, answer["id"]) == (200, acked_now[key])
        # each key is stored exactly once: acknowledged or in flight at the kill, never twice
        assert count_attempts(records_db) == len(sent_now)
    finally:
        server.stop()

"""kill -9 of the records server in the middle of a burst of uploads, on SQLite and PostgreSQL.

Eight clients send real uploads (recording and pack identity) with idempotency keys as fast as
the server acknowledges them; once enough were acknowledged the server process gets SIGKILL.
After a restart on the same database every acknowledged upload is there and is scored into an
attempt, and resending everything that was sent (acknowledged or not) with the same keys adds
each upload, and each attempt, at most once.
"""

from __future__ import annotations

import signal
import threading
import uuid

import pytest
from conftest import PASSWORD, call, count_attempts, populate, start_server, upload, wait_scored

from chainsim.game.records.store import RecordStore

# a server killed mid-burst and restarted, on both databases (a minute and a half on 2 cores): CI runs it
pytestmark = pytest.mark.slow

#: acknowledged uploads before the kill; each one costs a replay after the restart
ENOUGH = 24


def count_uploads(db: str) -> int:
    with RecordStore(db) as store:
        return store.query("SELECT COUNT(*) FROM uploads")[0][0]


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX SIGKILL")
def test_acknowledged_uploads_survive_kill_9_and_are_scored_once(records_db, tmp_path):
    populate(records_db)
    server = start_server(records_db, tmp_path / "serve.log")
    token = call(server, "POST", "/api/login", {"name": "alice", "password": PASSWORD})[1]["token"]
    base = upload("skull-hit.toml")
    acked: dict[str, int] = {}  # idempotency key -> upload id, for answered uploads
    sent: dict[str, dict] = {}  # every key a client tried, with its upload
    lock = threading.Lock()
    enough = threading.Event()
    stop = threading.Event()
    refused: list = []

    def client(n: int) -> None:
        i = 0
        while not stop.is_set():
            # the simulator's own duration tells the uploads apart (the replay's is kept beside it)
            key, body = uuid.uuid4().hex, {**base, "duration_s": float(1000 * n + i)}
            with lock:
                sent[key] = body
            try:
                status, answer, _ = call(server, "POST", "/api/attempts", body, token, {"Idempotency-Key": key})
            except OSError:  # the server died under this request: not acknowledged
                return
            if status != 202:
                refused.append((status, answer))
                enough.set()
                return
            with lock:
                acked[key] = answer["upload"]
                if len(acked) >= ENOUGH:
                    enough.set()
            i += 1

    threads = [threading.Thread(target=client, args=(n,)) for n in range(8)]
    for t in threads:
        t.start()
    try:
        assert enough.wait(120), f"the server did not acknowledge {ENOUGH} uploads"
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
        assert count_uploads(records_db) >= len(acked_now)
        for key, upload_id in acked_now.items():
            status, answer, _ = call(server, "POST", "/api/attempts", sent_now[key], token, {"Idempotency-Key": key})
            assert (status, answer["upload"]) == (200, upload_id), answer
        for key, body in sent_now.items():
            status, answer, _ = call(server, "POST", "/api/attempts", body, token, {"Idempotency-Key": key})
            assert status in (200, 202), answer
        # each key is one upload: acknowledged or in flight at the kill, never two
        assert count_uploads(records_db) == len(sent_now)
        for key, upload_id in acked_now.items():
            result = wait_scored(server, upload_id, token)
            assert result["status"] == "scored", result
            status, got, _ = call(server, "GET", f"/api/attempts/{result['attempt_id']}", token=token)
            assert status == 200 and got["client_figures"]["duration_s"] == sent_now[key]["duration_s"]
        with RecordStore(records_db) as store:
            waiting = [r[0] for r in store.query("SELECT id FROM uploads WHERE state = 'scoring'")]
        for upload_id in waiting:
            assert wait_scored(server, upload_id, token)["status"] == "scored"
        # and each upload one attempt
        assert count_attempts(records_db) == len(sent_now)
    finally:
        server.stop()

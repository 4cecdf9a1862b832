"""Killing the process in the middle of a save loses nothing already saved and leaves no partial attempt.

A child process saves some attempts, then starts one more save and is frozen inside its open
transaction (the attempt row already inserted, COMMIT not yet run); the parent SIGKILLs it there
and inspects the database. Synchronisation is a pipe handshake, never a sleep. Runs on an SQLite
file and on a PostgreSQL database (tests/records_db.py).
"""

from __future__ import annotations

import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from chainsim.game.records.migrations import LEGACY_METRICS
from chainsim.game.records.store import RecordStore
from chainsim.game.records.validate import AIDS

REPO = Path(__file__).resolve().parents[2]

CHILD = textwrap.dedent(
    """
    import sys
    from chainsim.game.records.store import RecordStore

    def attempt(i):
        return {"pack": "prp", "created_at": f"2026-04-0{i + 1}T08:00:00Z", "duration_s": 10.0 + i,
                "landmark_error_mm": 3.0 + i, "needle_error_mm": None if i == 1 else 2.0 * i,
                "target": "skull", "skull_contacts": i, "path_length_mm": 40.0 + i,
                "xray_shots": i, "exposure_s": 0.3 * i, "dose_mgy": 0.06 * i,
                "aids": {"tip_view": i % 2 == 0}, "step_times": {"insert": 5.0 + i}, "details": {"i": i}}

    store = RecordStore(sys.argv[1])
    for i in range(int(sys.argv[2])):
        store.save_attempt("c1", "alice", attempt(i))

    class FreezeBeforeCommit:
        # Sees each statement first: at COMMIT the attempt row is written but not committed.
        def __init__(self, conn):
            self.conn = conn

        def __getattr__(self, name):
            return getattr(self.conn, name)

        def execute(self, sql, *params):
            if sql.strip().upper() == "COMMIT":
                print("IN-SAVE", flush=True)
                sys.stdin.readline()
            return self.conn.execute(sql, *params)

    if store._conn is not None:
        store._conn = FreezeBeforeCommit(store._conn)
    else:  # a new database file is made by the first write
        open_file = store._open_file
        store._open_file = lambda: FreezeBeforeCommit(open_file())
    # A new class and trainee as well, so a half-done save would also leave them behind.
    store.save_attempt(sys.argv[3], "bob", attempt(8))
    print("SAVE-RETURNED", flush=True)
    """
)


def expected(i: int) -> dict:
    row = {
        "class_name": "c1",
        "trainee": "alice",
        "pack": "prp",
        "created_at": f"2026-04-0{i + 1}T08:00:00Z",
        "duration_s": 10.0 + i,
        "landmark_error_mm": 3.0 + i,
        "needle_error_mm": None if i == 1 else 2.0 * i,
        "target": "skull",
        "skull_contacts": i,
        "path_length_mm": 40.0 + i,
        "redirections": 0,
        "xray_shots": i,
        "exposure_s": 0.3 * i,
        "dose_mgy": 0.06 * i,
        "aids": {k: k == "tip_view" and i % 2 == 0 for k in AIDS},
        "step_times": {"insert": 5.0 + i},
        "details": {"i": i},
        # saved on this computer: no server filed or scored it
        "filed_by": None,
        "client_created_at": None,
        "pack_version": None,
        "pack_hash": None,
        "client_figures": None,
        "differences": [],
        "retracted_at": None,
        "retracted_by": None,
        "retract_reason": None,
        # saved locally: its source is local, its input judged by nobody
        "source": "local",
        "flags": [],
        "accepted_by": None,
        "accepted_at": None,
    }
    # the procedure-neutral metrics table holds every fixed-column value too, saved in the same transaction
    row["metrics"] = {k: None if row[k] is None else float(row[k]) for k in LEGACY_METRICS}
    return row


@pytest.mark.skipif(not hasattr(signal, "SIGKILL"), reason="needs POSIX SIGKILL")
@pytest.mark.parametrize("saved_before", [0, 3])
def test_sigkill_mid_save_keeps_earlier_records_and_drops_the_partial_one(tmp_path, records_db, saved_before):
    db = records_db
    sqlite = not records_db.startswith("postgresql://")
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(db), str(saved_before), "c2"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=tmp_path,
    )
    try:
        line = child.stdout.readline().strip()
        if line != "IN-SAVE":
            child.kill()
            _, err = child.communicate()
            pytest.fail(f"child did not reach the save: {line!r} {err}")
        # The partial attempt exists inside the child's open transaction right now.
        child.send_signal(signal.SIGKILL)
        assert child.wait() == -signal.SIGKILL
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        for stream in (child.stdin, child.stdout, child.stderr):
            stream.close()

    # The committed saves sit in the write-ahead log the dead process never checkpointed, so
    # reopening really exercises WAL recovery.
    if saved_before and sqlite:
        assert Path(f"{db}-wal").stat().st_size > 0

    with RecordStore(db) as store:
        rows = store.list_attempts()
        for row in rows:
            row.pop("id")
        assert rows == [expected(i) for i in range(saved_before)]
        assert "c2" not in store.list_classes()
        assert all(t["trainee"] != "bob" for t in store.list_trainees())
        # Still writable after the crash.
        store.save_attempt(
            "c2",
            "bob",
            {
                "pack": "prp",
                "duration_s": 1.0,
                "landmark_error_mm": 1.0,
                "needle_error_mm": 1.0,
                "target": "skull",
                "skull_contacts": 0,
                "path_length_mm": 1.0,
            },
        )

        assert len(store.list_attempts()) == saved_before + 1
    if sqlite:
        conn = sqlite3.connect(db)
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert conn.execute("SELECT COUNT(*) FROM attempts").fetchone()[0] == saved_before + 1
        conn.close()

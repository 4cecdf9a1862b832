"""The store under the server: today's files migrate keeping every row, PostgreSQL databases are
checked before use, $CHAINSIM_DB may be a URL, and several connections in one process (the
server's worker threads) never lose each other's writes to a second process."""

from __future__ import annotations

import os
import sqlite3
import subprocess
import sys
import threading

import pytest
from conftest import REPO, attempt

from chainsim.game.records import accounts
from chainsim.game.records.migrations import SCHEMA_VERSION, V1_DDL, V2_DDL
from chainsim.game.records.store import ENV_VAR, RecordStore
from chainsim.systems.engine.errors import UserError


def test_version_2_file_is_migrated_keeping_every_row(tmp_path):
    path = tmp_path / "today.sqlite3"
    conn = sqlite3.connect(path)
    for stmt in V1_DDL + V2_DDL:
        conn.execute(stmt)
    conn.execute("INSERT INTO classes (id, name) VALUES (1, 'c1')")
    conn.execute("INSERT INTO trainees (id, class_id, name) VALUES (1, 1, 'alice')")
    for i in range(5):
        conn.execute(
            "INSERT INTO attempts (trainee_id, pack, created_at, duration_s, landmark_error_mm, needle_error_mm, "
            "target, skull_contacts, path_length_mm, aids, step_times, details) "
            "VALUES (1, 'prp', ?, ?, 2.5, NULL, 'skull', 1, 40.0, '{}', '{\"insert\": 3.0}', '{\"D1\": 1.0}')",
            (f"2026-01-0{i + 1}T08:00:00Z", 10.0 + i),
        )
    conn.execute("PRAGMA user_version = 2")
    conn.commit()
    conn.close()
    with RecordStore(path) as store:
        assert store.schema_version == SCHEMA_VERSION
        rows = store.list_attempts()
        assert [r["duration_s"] for r in rows] == [10.0, 11.0, 12.0, 13.0, 14.0]
        assert rows[0]["step_times"] == {"insert": 3.0} and rows[0]["details"] == {"D1": 1.0}
        # the old trainee can be given an account, keeping its attempts
        user = accounts.add_user(store, "alice", "trainee", "long enough pw", ["c1"])
        assert user.trainee_id == 1 and user.can_see("c1", "alice")


def test_postgres_database_of_something_else_is_refused_untouched(postgres_server):
    import psycopg

    url = postgres_server.new_database()
    with psycopg.connect(url, autocommit=True) as conn:
        conn.execute("CREATE TABLE invoices (id int)")
    with pytest.raises(UserError) as e:
        RecordStore(url)
    assert "invoices" in str(e.value) and "\n" not in str(e.value)
    with psycopg.connect(url, autocommit=True) as conn:
        tables = {
            r[0] for r in conn.execute("SELECT table_name FROM information_schema.tables WHERE table_schema = 'public'")
        }
    assert tables == {"invoices"}


def test_postgres_url_from_env_and_unreachable_server(postgres_server, monkeypatch):
    url = postgres_server.new_database()
    monkeypatch.setenv(ENV_VAR, url)
    with RecordStore() as store:
        store.save_attempt("c1", "alice", attempt())
    with RecordStore(url) as store:
        assert len(store.list_attempts()) == 1
        assert store.path == url  # no password in this URL, nothing to hide
    bad = "postgresql://chainsim:secret@127.0.0.1:1/nothing"
    with pytest.raises(UserError) as e:
        RecordStore(bad)
    assert "cannot connect" in str(e.value) and "secret" not in str(e.value)


def test_concurrent_migrations_on_postgres_run_once(postgres_server):
    url = postgres_server.new_database()
    errors = []

    def open_once():
        try:
            RecordStore(url).close()
        except Exception as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=open_once) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    with RecordStore(url) as store:
        assert store.schema_version == SCHEMA_VERSION


SERVER_LIKE = """
import os, subprocess, sys
from chainsim.game.records.store import RecordStore
a = {"pack": "prp", "duration_s": 1.0, "landmark_error_mm": 1.0, "needle_error_mm": 1.0, "target": "skull",
     "skull_contacts": 0, "path_length_mm": 1.0}
path = sys.argv[1]
first = RecordStore(path)
first.save_attempt("c1", "alice", a)
second = RecordStore(path)  # a second worker thread's store, opened while the first is live
second.save_attempt("c1", "alice", a)
for i in range(3):
    code = f"from chainsim.game.records.store import RecordStore\\nwith RecordStore({path!r}) as s: s.add_class('x{i}')"
    subprocess.run([sys.executable, "-c", code], check=True)
    first.save_attempt("c1", "alice", a)
    second.save_attempt("c1", "alice", a)
os._exit(0)  # killed: nothing closed
"""


def test_second_store_in_one_process_keeps_its_locks_against_other_processes(tmp_path):
    # The server keeps one connection per worker thread. Opening one while another is live must
    # leave the live one's locks in place; if the file were opened and closed with a plain handle
    # (closing any descriptor drops the process's POSIX locks on the file), the other process
    # would take itself for the last user, checkpoint and delete the WAL, and the writes that
    # follow would go to a deleted file.
    path = tmp_path / "r.sqlite3"
    RecordStore(path).close()
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    subprocess.run([sys.executable, "-c", SERVER_LIKE, str(path)], check=True, env=env)
    with RecordStore(path) as store:
        assert len(store.list_attempts()) == 8
        assert store.list_classes() == ["c1", "x0", "x1", "x2"]

"""Where an attempt came from, kept and shown: the store, its migration, the CSV export and xAPI.

Attempts a server stored before provenance existed read as replayed, those saved locally as local;
a replayed attempt's flags and a trainer's acceptance travel with it into the CSV export and the
xAPI statement, and a flagged attempt counts in the class figures only once accepted.
"""

from __future__ import annotations

import csv
import sqlite3

import pytest

from chainsim.game.records import report, xapi
from chainsim.game.records.migrations import MIGRATIONS, SCHEMA_VERSION
from chainsim.game.records.store import RecordStore, in_class_figures
from chainsim.game.records.validate import clean_attempt
from chainsim.systems.engine.errors import UserError

ATTEMPT = {
    "pack": "prp",
    "created_at": "2026-03-01T09:15:00Z",
    "duration_s": 0.72,
    "landmark_error_mm": 1.0,
    "needle_error_mm": -1.0,
    "target": "foramen_ovale_left",
    "skull_contacts": 0,
    "path_length_mm": 55.5,
    "aids": {},
    "step_times": {},
    "details": {},
}
FLAGS = ["the attempt took 0.72 s; this procedure cannot be done in under 2.5 s"]


def stored(store: RecordStore, source: str, flags: list[str]) -> int:
    with store.transaction() as conn:
        return store.insert_attempt(
            conn,
            "c1",
            "alice",
            clean_attempt(ATTEMPT),
            provenance={"filed_by": "alice", "source": source, "flags": flags},
        )


def test_a_flagged_attempt_counts_only_once_a_trainer_accepts_it(tmp_path):
    with RecordStore(str(tmp_path / "r.sqlite3")) as store:
        local = store.save_attempt("c1", "alice", ATTEMPT)
        flagged = stored(store, "replayed", FLAGS)
        witnessed = stored(store, "witnessed", [])
        by_id = {a["id"]: a for a in store.list_attempts("c1")}
        assert (by_id[local]["source"], by_id[flagged]["source"], by_id[witnessed]["source"]) == (
            "local",
            "replayed",
            "witnessed",
        )
        assert [in_class_figures(by_id[i]) for i in (local, flagged, witnessed)] == [True, False, True]
        with pytest.raises(UserError, match="not flagged"):
            store.accept_attempt(local, "tina")
        accepted = store.accept_attempt(flagged, "tina")
        assert accepted["accepted_by"] == "tina" and in_class_figures(accepted)
        assert ("accept", flagged) in [(a["action"], a["attempt_id"]) for a in store.audit_entries(["c1"])]
        rows = store.list_attempts("c1")
    path = tmp_path / "out.csv"
    report.export_csv(rows, path)
    with path.open(newline="") as fh:
        table = list(csv.DictReader(fh))
    assert [(r["source"], r["flags"], r["accepted_by"]) for r in table] == [
        ("local", "", ""),
        ("replayed", FLAGS[0], "tina"),
        ("witnessed", "", ""),
    ]
    statements = xapi.statements(rows)
    ext = f"{xapi.DEFAULT_HOMEPAGE}/xapi/extensions"
    assert [s["context"]["extensions"][f"{ext}/source"] for s in statements] == ["local", "replayed", "witnessed"]
    assert not any(s["context"]["extensions"][f"{ext}/flagged"] for s in statements)  # accepted
    assert all(f"{ext}/source" not in s["result"]["extensions"] for s in statements)


def test_a_version_8_database_reads_its_server_attempts_as_replayed(tmp_path):
    path = tmp_path / "v8.sqlite3"
    conn = sqlite3.connect(path)
    for step in MIGRATIONS[:8]:
        for stmt in step:
            conn.execute(stmt)
    conn.execute("INSERT INTO classes (name) VALUES ('c1')")
    conn.execute("INSERT INTO trainees (class_id, name) VALUES (1, 'alice')")
    row = (
        "INSERT INTO attempts (trainee_id, pack, created_at, duration_s, landmark_error_mm, needle_error_mm, target, "
        "skull_contacts, path_length_mm, aids, step_times, filed_by) VALUES (1, 'prp', '2026-01-01T00:00:00Z', 60, 1, "
        "2, 'skull', 0, 50, '{}', '{}', ?)"
    )
    conn.execute(row, ("alice",))
    conn.execute(row, (None,))
    conn.execute("PRAGMA user_version = 8")
    conn.commit()
    conn.close()
    with RecordStore(path) as store:
        assert store.schema_version == SCHEMA_VERSION
        got = store.list_attempts("c1")
    assert [(a["filed_by"], a["source"], a["flags"]) for a in got] == [("alice", "replayed", []), (None, "local", [])]

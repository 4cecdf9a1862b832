"""The same attempts export as they did before the records kept figures by name (schema version 13).

records_exports/ holds three attempts (attempts.json: a needle that touched nothing, a pack metric
sharing a figure's name with another value, every aid, X-ray costs, marked points) and what the
chainsim of schema version 12 made of them: the CSV export, the xAPI statements and the attempts as
the store gave them (expected.*), and its database as an SQL dump (v12.sql). Saved today, on SQLite
and on PostgreSQL, or read from that database after it migrates, the attempts export byte for byte
the same.
"""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

from chainsim.game.records import report, xapi
from chainsim.game.records.store import RecordStore

HERE = Path(__file__).parent / "records_exports"


def _exports(store: RecordStore, out: Path) -> dict[str, bytes]:
    rows = store.list_attempts()
    report.export_csv(rows, out / "attempts.csv")
    return {
        "expected.csv": (out / "attempts.csv").read_bytes(),
        "expected.xapi.json": xapi.dumps(xapi.statements(rows)).encode(),
        "expected.attempts.json": (json.dumps(rows, indent=1) + "\n").encode(),
    }


def _assert_as_before(got: dict[str, bytes]) -> None:
    for name, data in got.items():
        assert data == (HERE / name).read_bytes(), name


def test_attempts_saved_today_export_as_they_did(records_db, tmp_path):
    with RecordStore(records_db) as s:
        for item in json.loads((HERE / "attempts.json").read_text()):
            s.save_attempt(item["class"], item["trainee"], item["attempt"])
        _assert_as_before(_exports(s, tmp_path))


def test_a_database_saved_before_exports_as_it_did_after_it_migrates(tmp_path):
    path = tmp_path / "v12.sqlite3"
    conn = sqlite3.connect(path)
    conn.executescript((HERE / "v12.sql").read_text())
    conn.close()
    with RecordStore(path) as s:
        assert s.schema_version == 13
        _assert_as_before(_exports(s, tmp_path))

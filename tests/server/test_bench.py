"""`chainsim bench records` runs, stops by itself, and its count check holds (both backends).

Only that it works is tested here; its figures are in docs/records-server.md."""

from __future__ import annotations

from chainsim.game.records.store import RecordStore
from chainsim.game.server.bench import run_bench


def test_bench_runs_bounded_and_loses_nothing(records_db, cli):
    result = run_bench(records_db, clients=3, seconds=1.0)
    assert result["acknowledged"] > 0 and result["errors"] == 0
    assert result["count_ok"] and result["stored"] == result["acknowledged"]
    assert result["p50_ms"] <= result["p95_ms"] <= result["max_ms"]
    with RecordStore(records_db) as store:  # the bench cleans up after itself
        assert store.list_classes() == [] and store.query("SELECT COUNT(*) FROM users")[0][0] == 0
    code, _, err = cli("bench", "records", "--clients", "0", "--seconds", "1")
    assert code == 2 and "--clients" in err

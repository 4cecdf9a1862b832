"""`chainsim bench records` sends real uploads, waits for their scoring and its count check holds (both backends).

Only that it works and measures what it says is tested here; its figures are in docs/records-server.md."""

from __future__ import annotations

import pytest

from chainsim.game.records.store import RecordStore
from chainsim.tools.bench.records import run_bench


@pytest.mark.slow
def test_bench_sends_real_uploads_scores_each_once_and_cleans_up(records_db, cli):
    result = run_bench(records_db, clients=3, attempts=2, scorers=2)
    assert result["acknowledged"] == 6 and result["errors"] == 0 and result["refused"] == 0
    assert result["scored"] == result["stored"] == 6 and result["count_ok"]
    assert 0 < result["ack_p50_ms"] <= result["ack_p99_ms"] <= result["ack_max_ms"]
    assert 0 < result["scoring_p50_s"] <= result["scoring_p99_s"] <= result["scoring_max_s"]
    replay = result["replay"]
    assert replay["simulated_s"] > 1.0 and replay["replay_s"] > 0
    assert replay["replay_s_per_simulated_s"] == pytest.approx(replay["replay_s"] / replay["simulated_s"], rel=0.01)
    assert replay["replay_cpu_s"] > 0
    assert replay["simulated_s_per_cpu_s"] == pytest.approx(replay["simulated_s"] / replay["replay_cpu_s"], rel=0.05)
    with RecordStore(records_db) as store:  # the bench cleans up after itself
        assert store.list_classes() == [] and store.query("SELECT COUNT(*) FROM users")[0][0] == 0
        assert store.query("SELECT COUNT(*) FROM uploads")[0][0] == 0


def test_bench_arguments_are_checked_with_one_line(cli):
    for args, named in ((("--clients", "0"), "--clients"), (("--attempts", "0"), "--attempts")):
        code, _, err = cli("bench", "records", *args)
        assert code == 2 and named in err and len(err.strip().splitlines()) == 1, err

"""`chainsim bench chainmail --mesh ... --json`: one cascade timed from the rest state, JSON on stdout."""

from __future__ import annotations

import json

import numpy as np

from chainsim.game.cli.main import main
from chainsim.systems.engine import meshgen


def test_single_mesh_timing_reports_json(tmp_path, capsys):
    pos, tets, links = meshgen.tet_grid(6, 6, 6)
    np.savez(tmp_path / "v.npz", positions=pos, links=links)
    code = main(
        [
            "bench",
            "chainmail",
            "--mesh",
            str(tmp_path / "v.npz"),
            "--grab",
            "0",
            "--to",
            "-1",
            "-1",
            "-1",
            "--alpha-min",
            "1",
            "--alpha-max",
            "1",
            "--beta",
            "0",
            "--repeat",
            "3",
            "--json",
        ]
    )
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["elements"] == len(pos) and out["links"] == len(links)
    assert out["elements_moved"] == len(pos)  # rigid: the whole block follows, every repeat from rest
    assert out["median_ms"] > 0 and out["repeats"] == 3


def test_single_mesh_timing_refuses_bad_input(tmp_path, capsys):
    pos, links = meshgen.grid((4, 4))
    np.savez(tmp_path / "g.npz", positions=pos, links=links)
    for extra, needle in (
        (["--grab", "99", "--to", "1", "1"], "--grab"),
        (["--grab", "1", "--to", "1"], "--to"),
        (["--grab", "1", "--to", "1", "1", "--beta", "-2"], "--beta"),
    ):
        code = main(["bench", "chainmail", "--mesh", str(tmp_path / "g.npz"), *extra])
        err = capsys.readouterr().err
        assert code == 2 and needle in err and len(err.strip().splitlines()) == 1


def test_drag_and_threads_parts_report_the_lean_cascade_beside_every_row(tmp_path):
    out = tmp_path / "b"
    code = main(
        ["bench", "chainmail", "--parts", "drag,threads", "--max-elements", "1000", "--repeat", "1", "--out", str(out)]
    )
    assert code == 0
    res = json.loads((out / "results.json").read_text())
    drag = res["drag"]
    assert {(r["material"], r["dtype"]) for r in drag} == {
        (m, d) for m in ("soft-tissue", "very-soft") for d in ("float64", "float32")
    }
    for r in drag:
        assert r["frames"] == 12 and r["body_ms"] > 0 and r["lean_ms"] > 0
        assert r["moved_last"] > 1 and r["lean_moved_last"] > 1
        if r["dtype"] == "float64":
            assert r["same_as_lean"] and r["moved_last"] == r["lean_moved_last"]
    threads = res["threads"]
    assert threads and all(r["serial_ms"] > 0 and r["parallel_ms"] > 0 for r in threads)
    assert not any(r["rule_picks_parallel"] for r in threads)  # 1000 elements: below the rule's size
    md = (out / "results.md").read_text()
    assert "beside the lean cascade" in md and "thread count" in md

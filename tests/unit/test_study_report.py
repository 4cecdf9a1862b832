"""The study's report: tables, plots and strict JSON from a tiny run; the per-system pack table."""

import json

import numba

from chainsim.tools.study import report
from chainsim.tools.study import speed_accuracy as sa
from chainsim.tools.study.chainmail_model import ChainMailParams


def test_tiny_study_writes_report_plots_and_strict_json(tmp_path, monkeypatch):
    numba.set_num_threads(1)
    monkeypatch.setattr(sa, "RELAX", [0, 2])
    rows, timings = [], []
    limits = {"nl": 200, "lin": 400, "ms": 400, "ms_explicit": 0}
    materials = {"medium": ChainMailParams(0.8, 1.2, 0.1)}
    sa.run_scene("block", [5, 7], [0.01, 0.1], limits, materials, 1, rows, timings)
    results = {
        "mode": "quick",
        "material": {"E": sa.E_STUDY, "nu": sa.NU_STUDY},
        "strains": [0.01, 0.1],
        "pareto_strain": 0.1,
        "limits": limits,
        "rows": rows,
        "timings": timings,
        "stability": sa.stability_sweep(n=5),
        "realtime": sa.realtime_table(rows, timings),
        "chainmail_settings": {k: vars(v) for k, v in materials.items()},
        "elapsed_cpu_s": 1.0,
        "elapsed_wall_s": 1.0,
        "clock": "thread CPU",
    }
    summary = {
        "pack": "demo",
        "scene": "s",
        "systems": {
            "simulation/deformation": {"mean_ms": 3.0, "max_ms": 9.0},
            "input/view": {"mean_ms": 1.0, "max_ms": 2.0},
        },
    }
    md = report.write(results, tmp_path, [summary], "note")
    text = md.read_text()
    assert "block: Pareto table at 10% pull" in text
    assert "| 125 | linear FEM |" in text and "ChainMail medium r2" in text
    assert "simulation/deformation" in text and "75%" in text
    for png in ("pareto_block.png", "error_vs_displacement.png", "mass_spring_stability.png"):
        assert (tmp_path / png).stat().st_size > 1000
    data = json.loads(
        (tmp_path / "results.json").read_text(), parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c))
    )
    models = {r["model"] for r in data["rows"]}
    assert {"neo-Hookean FEM", "linear FEM", "mass-spring symplectic", "ChainMail medium r0"} <= models
    # the 7^3 mesh has no nonlinear FEM of its own: it is scored against the composite reference
    fine = [r for r in data["rows"] if r["nodes"] == 343 and r["model"] == "linear FEM"]
    assert fine and all(r["reference"].startswith("linear FEM + nonlinear correction") for r in fine)


def test_frame_cost_table_without_summaries():
    assert "no pack summaries" in report.frame_cost_table([])

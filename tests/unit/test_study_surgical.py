"""The surgical-scale study: its scenes are tissue-sized, its errors are measured two ways, and its rows
reach the model table `auto` reads without dropping other scenes' rows."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from chainsim.systems.engine.bodies.factory import load_table
from chainsim.systems.engine.errors import UserError
from chainsim.tools.study import surgical, surgical_report


def _tiny(monkeypatch):
    monkeypatch.setitem(surgical.SIZES, "quick", [5.0, 2.5])
    monkeypatch.setattr(surgical, "FRAMES", 3)
    return surgical.run("quick")


def test_the_block_is_tissue_sized_with_a_fixed_base_and_a_held_patch():
    b = surgical.block(2.5)
    assert np.allclose(np.ptp(b.pos, axis=0), surgical.BLOCK_MM)
    assert np.all(b.pos[b.fixed, 2] == 0.0) and len(b.fixed) == 13 * 13
    assert np.all(b.pos[b.grabbed, 2] == surgical.BLOCK_MM[2]) and len(b.grabbed) == 3 * 3


def test_a_run_measures_solver_and_physical_error_for_every_setting(monkeypatch):
    res = _tiny(monkeypatch)
    rows = res["rows"]
    base = {"baseline: held patch only", "baseline: distance blend"}
    assert {r["setting"] for r in rows} == {s for _m, s, _p in surgical.SETTINGS} | base
    # the baselines score against the same references, and the physical models beat both
    for mesh in (5.0, 2.5):
        sel = [r for r in rows if r["element_mm"] == mesh]
        floor = min(r["solver_error"] for r in sel if r["setting"] in base)
        assert all(r["solver_error"] < floor for r in sel if r["model"] in ("xpbd", "projective")), mesh
    rows = [r for r in rows if r["model"] != "baseline"]
    coarse = [r for r in rows if r["element_mm"] == 5.0]
    fine = [r for r in rows if r["element_mm"] == 2.5]
    # the coarse mesh is scored against the finer mesh's FEM; the finest gets an estimate, marked
    assert all("physical_error" in r and not r.get("physical_estimated") for r in coarse)
    assert all(r.get("physical_estimated") for r in fine if "physical_error" in r)
    for r in rows:
        assert np.isfinite(r["solver_error"]) and r["ms_per_frame"] > 0
        assert np.isfinite(r["volume_change"]) and np.isfinite(r["reference_volume_change"])
    # the physical models invert nothing under the lift
    assert all(r["min_J"] > 0 for r in rows if r["model"] != "chainmail")
    # the FEM solution scores zero solver error against itself; a live model does not beat physics for free
    assert all(r["physical_error"] >= 0.5 * r["mesh_error"] for r in coarse if "mesh_error" in r)


def test_the_rows_merge_into_the_table_auto_reads(monkeypatch, tmp_path):
    res = _tiny(monkeypatch)
    table = tmp_path / "models.toml"
    table.write_text(
        '[[rows]]\nscene = "block"\nnodes = 512\nmodel = "xpbd"\nsetting = "old"\nrms_error = 0.1\n'
        "ms_per_update = 1.0\n"
    )
    md = surgical_report.write(res, tmp_path / "out", "chainsim study surgical --quick", "test machine", table)
    rows = load_table(table)
    assert {r["scene"] for r in rows} == {"block", "tissue-block"}
    tissue = [r for r in rows if r["scene"] == "tissue-block"]
    assert {r["model"] for r in tissue} == {"chainmail", "xpbd", "projective", "hybrid"}
    assert all("params" in r and "E" in r for r in tissue)
    text = md.read_text()
    assert "chainsim study surgical --quick" in text and "physical error" in text
    assert (tmp_path / "out" / "surgical-tradeoff.png").stat().st_size > 1000
    # merging again replaces the tissue rows, never duplicates them
    surgical_report.merge_table(table, surgical.model_table(res)["rows"])
    assert len(tomllib.loads(table.read_text())["rows"]) == len(rows)


def test_a_table_that_is_not_a_model_table_is_one_clear_line(tmp_path):
    bad = tmp_path / "models.toml"
    bad.write_text("rows = [[[")
    with pytest.raises(UserError, match="cannot read it as a model table"):
        surgical_report.merge_table(bad, [])

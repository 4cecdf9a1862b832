"""`chainsim bench models`: both phases are measured and written; bad arguments are one clear line."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest

from chainsim.systems.engine.errors import UserError
from chainsim.tools.bench import models


def test_bench_models_measures_both_phases(tmp_path):
    args = SimpleNamespace(scene="block", n=6, frames=200, only="xpbd, 1;projective statics, CG 6", out=str(tmp_path))
    assert models.run(args) == 0
    info = json.loads((tmp_path / "results.json").read_text())
    assert [r["setting"] for r in info["rows"]] == ["xpbd, 1 substep", "projective statics, CG 6, 1 iteration"]
    for r in info["rows"]:
        assert r["frames_to_5_percent_from_rest"] is not None  # a small block converges within the bound
        assert r["rms_error_after_next_pull"] <= models.TARGET
        assert r["ms_per_frame_median"] > 0
    assert "frames to 5 % after the next 5 % pull" in (tmp_path / "results.md").read_text()


def test_bench_models_on_the_tissue_block_settles_projective_and_xpbd_under_its_rule(tmp_path):
    args = SimpleNamespace(
        scene="tissue",
        element_mm=5.0,
        E=3e4,
        nu=0.45,
        n=6,
        frames=150,
        only="xpbd, substeps by rule;projective statics, CG 20",
        out=str(tmp_path),
    )
    assert models.run(args) == 0
    info = json.loads((tmp_path / "results.json").read_text())
    assert info["nodes"] == 245 and "tissue block of 5 mm" in info["scene"]
    for r in info["rows"]:
        assert r["frames_to_5_percent_from_rest"] is not None, r["setting"]


@pytest.mark.parametrize(
    "kw, word",
    [
        ({"n": 3}, "--n"),
        ({"frames": 0}, "--frames"),
        ({"only": "mass-spring"}, "--only"),
        ({"scene": "tissue", "E": 5.0}, "--E"),
        ({"scene": "tissue", "element_mm": 0.1}, "--element-mm"),
        ({"threads": 0}, "--threads"),
        ({"threads": 10_000}, "--threads"),
    ],
)
def test_bench_models_refuses_bad_arguments(tmp_path, kw, word):
    base = {"scene": "block", "n": 6, "frames": 10, "only": None, "out": str(tmp_path), "E": 3e4, "nu": 0.45}
    args = SimpleNamespace(**{**base, "element_mm": 1.25, **kw})
    with pytest.raises(UserError, match=word):
        models.run(args)

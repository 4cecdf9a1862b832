"""`model = "auto"`: the selection rule, and every row of the shipped table builds exactly its setting."""

from __future__ import annotations

import esper
import numpy as np
import pytest

import chainsim.systems.tissue.deformable as deformable
from chainsim.game.trainer.headless import build_app
from chainsim.systems.engine.bodies.factory import ROW_PARAMS, Choice, choose_model, load_table, make_body
from chainsim.systems.engine.bodies.hybrid import coarse_spacing
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.meshgen import tet_grid
from chainsim.systems.tissue.deformable import MODEL_TABLE, Deformable, use_model


def _row(model, err, ms, nodes=1000, E=None, **params):
    r = {"scene": "tissue-block", "nodes": nodes, "model": model, "setting": f"{model} {err}", "params": params}
    r.update(rms_error=err, ms_per_update=ms)
    if E is not None:
        r["E"] = E
    return r


TABLE = [
    _row("chainmail", 0.20, 0.05, relax=0),
    _row("chainmail", 0.15, 0.3, relax=4),
    _row("xpbd", 0.04, 9.0, substeps="auto"),
    _row("projective", 0.03, 14.0, iterations=10),
    _row("projective", 0.02, 40.0, iterations=30),
]


def test_an_error_budget_takes_the_cheapest_row_that_meets_it():
    c = choose_model(TABLE, scene="tissue-block", nodes=1000, error_budget=0.05)
    assert (c.model, c.rms_error) == ("xpbd", 0.04) and "cheapest" in c.reason


def test_a_time_budget_takes_the_most_accurate_row_that_fits_it():
    c = choose_model(TABLE, scene="tissue-block", nodes=1000, time_budget_ms=15.0)
    assert (c.model, c.rms_error) == ("projective", 0.03) and "most accurate" in c.reason
    c = choose_model(TABLE, scene="tissue-block", nodes=1000, time_budget_ms=1.0)
    assert (c.model, c.rms_error) == ("chainmail", 0.15)


def test_both_budgets_take_the_cheapest_meeting_both_else_the_most_accurate_in_time():
    c = choose_model(TABLE, scene="tissue-block", nodes=1000, error_budget=0.1, time_budget_ms=50.0)
    assert c.rms_error == 0.04
    c = choose_model(TABLE, scene="tissue-block", nodes=1000, error_budget=0.01, time_budget_ms=20.0)
    assert c.rms_error == 0.03 and "nothing meets" in c.reason


def test_no_budget_keeps_to_one_frame_and_times_scale_with_size():
    assert choose_model(TABLE, scene="tissue-block", nodes=1000).rms_error == 0.03
    # twice the nodes: the 9 and 14 ms rows cost 18 and 28 ms, past a 60 Hz frame
    assert choose_model(TABLE, scene="tissue-block", nodes=2000).rms_error == 0.15


def test_the_nearest_stiffness_is_used_where_the_table_has_several():
    table = [_row("xpbd", 0.04, 5.0, E=1e3), _row("xpbd", 0.04, 50.0, E=1e5), _row("chainmail", 0.2, 0.1, E=1e5)]
    assert choose_model(table, scene="tissue-block", nodes=1000, E=2e3, time_budget_ms=10).model == "xpbd"
    c = choose_model(table, scene="tissue-block", nodes=1000, E=8e4, time_budget_ms=10)
    assert c.model == "chainmail" and "E = 100000 Pa" in c.reason


def test_a_row_with_a_setting_the_model_lacks_is_refused(tmp_path):
    p = tmp_path / "t.toml"
    p.write_text(
        '[[rows]]\nscene="b"\nnodes=1\nmodel="xpbd"\nsetting="s"\nrms_error=0.1\nms_per_update=1\n'
        "[rows.params]\nrelax=3\n"
    )
    with pytest.raises(UserError, match=r"rows\[0\]\.params"):
        load_table(p)


def test_make_body_builds_chainmail_too():
    pos, tets, _ = tet_grid(3, 3, 3, spacing=1.0)
    b = make_body("chainmail", pos, tets=tets, alpha_min=0.7, alpha_max=1.3, beta=0.2, relax=3)
    assert b.model == "chainmail" and b.relax_iterations == 3
    assert np.all(b.amin == 0.7) and np.all(b.amax == 1.3) and np.all(b.beta == 0.2)


def _check_body(body, model, params):
    assert body.model == model
    for key, want in params.items():
        if model == "chainmail":
            got = {"alpha_min": body.amin, "alpha_max": body.amax, "beta": body.beta}.get(key)
            if got is None:
                assert body.relax_iterations == want
            else:
                assert np.all(got == want), key
        elif key == "substeps":
            assert body.substeps_setting == want
        elif key == "coarse":  # "auto": the spacing the body takes for its Poisson ratio
            assert body.coarse == coarse_spacing(want, float(np.max(body.lam / (2 * (body.lam + body.mu))))), key
        else:
            assert getattr(body, key) == want, key


def test_every_row_of_the_shipped_table_builds_exactly_its_setting(monkeypatch):
    rows = load_table(MODEL_TABLE)
    assert {r["model"] for r in rows} == set(ROW_PARAMS)
    app = build_app("chainmail-demo/volume", settings={"model": "chainmail"})
    try:
        with app.active():
            _ent, d = esper.get_component(Deformable)[0]
        for r in rows:
            assert set(r["params"]) <= set(ROW_PARAMS[r["model"]])
            choice = Choice(r["model"], r["setting"], r["rms_error"], "test", dict(r["params"]))
            monkeypatch.setattr(deformable, "choose_model", lambda *a, _c=choice, **k: _c)
            use_model(d, "auto")
            _check_body(d.body.model_body, r["model"], r["params"])
            assert d.body.model_reason.startswith(f"auto: {r['model']} ({r['setting']})")
    finally:
        app.close()


def test_the_shipped_table_has_every_live_model_at_every_surgical_size():
    rows = [r for r in load_table(MODEL_TABLE) if r["scene"] == "tissue-block"]
    sizes = sorted({r["nodes"] for r in rows})
    assert len(sizes) >= 3 and sizes[-1] >= 10_000
    for n in sizes:
        assert {r["model"] for r in rows if r["nodes"] == n} >= {"chainmail", "xpbd", "projective"}, n


def test_a_row_no_better_than_the_baselines_is_taken_only_when_nothing_else_fits():
    table = [dict(_row("chainmail", 0.19, 0.1), beats_baselines=False), _row("projective", 0.05, 10.0)]
    assert choose_model(table, scene="tissue-block", nodes=1000, time_budget_ms=12).model == "projective"
    c = choose_model(table, scene="tissue-block", nodes=1000, time_budget_ms=1)
    assert c.model == "chainmail" and "no-physics baselines" in c.reason


def test_auto_takes_the_hybrid_body_where_the_shipped_table_measures_it_best():
    """On the 10k-node tissue block in one 60 Hz frame the shipped table's most accurate row is a hybrid
    setting (chainsim study surgical); the body `auto` builds is that hybrid body with the row's settings."""
    table = load_table(MODEL_TABLE)
    c = choose_model(table, scene="tissue-block", nodes=10_625, E=3e4)
    rows = [r for r in table if r["scene"] == "tissue-block" and r["nodes"] == 10_625 and r.get("E") == 3e4]
    fits = [r for r in rows if r["ms_per_update"] <= 16.7 and r.get("beats_baselines", True)]
    assert c.model == "hybrid" and c.rms_error == min(r["rms_error"] for r in fits)
    pos, tets, _ = tet_grid(4, 4, 4, spacing=1.25)
    body = make_body(c.model, pos, tets=tets, **c.params)
    _check_body(body, c.model, c.params)


def test_a_bodys_cost_notice_is_said_with_its_model_at_the_scenes_start(monkeypatch):
    from chainsim.systems.engine import framecost
    from chainsim.systems.tissue.deformation import model_lines

    app = build_app("chainmail-demo/volume", settings={"model": "chainmail"})
    try:
        with app.active():
            _ent, d = esper.get_component(Deformable)[0]
            use_model(d, "projective")
            assert d.body.model_reason == "projective (as the pack or --model asks)"  # fits a frame: nothing said
            assert model_lines(auto_only=True) == []
            monkeypatch.setattr(framecost, "FRAME_MS", 1e-6)  # a machine where no frame fits
            use_model(d, "projective")
            assert d.body.model_body.notice and "\n" not in d.body.model_body.notice
            assert d.body.model_reason.endswith(f"; {d.body.model_body.notice}")
            [line] = model_lines(auto_only=True)
            assert line.endswith(f": projective - {d.body.model_body.notice}")
    finally:
        app.close()

"""Soft-tissue models in scenes: every body runs ChainMail, XPBD or projective dynamics through the same
component, requests and tools; the choice comes from the pack, --model, the m key, or a budget."""

from __future__ import annotations

import esper
import numpy as np
import pytest

from chainsim.assets import ASSETS_DIR
from chainsim.components.input_events import Widget
from chainsim.components.resources import PendingInput
from chainsim.game.trainer.headless import build_app, run_pack
from chainsim.systems.engine.bodies.factory import choose_model
from chainsim.systems.tissue.deformable import Deformable

CUT_SCRIPT = ASSETS_DIR / "cutting" / "scripts" / "cut-and-open.toml"


@pytest.mark.parametrize("model", ["chainmail", "xpbd", "projective", None])
def test_the_cutting_trainer_lifts_and_cuts_under_every_model(model, tmp_path):
    settings = {"model": model} if model else {}
    s = run_pack("cutting", script=str(CUT_SCRIPT), settings=settings, out=str(tmp_path))
    # with no --model the layers run the pack's SurfaceChainMail (thesis 4.5)
    assert {v["model"] for v in s["models"].values()} == {model or "surface"}
    a = s["assessment"]
    assert a["links_cut_by_layer"]["dura"] > 0  # the scissors cut the top layer
    assert a["links_cut_by_layer"]["arachnoid"] == 0  # and only it
    assert a["max_displacement_mm"] > 10.0  # the forceps lifted it
    assert a["elements_moved_by_layer"]["dura"] > 50  # and the tissue around followed


def test_the_m_key_switches_models_live_from_rest():
    app = build_app("cutting", settings={"model": "chainmail"})
    try:
        seen = []
        for _ in range(4):
            app.resource(PendingInput).push(app.time.sim_time, Widget("model", True))
            for _ in range(2):
                app.update(app.time.dt)
            with app.active():
                models = {d.body.model_used for _, d in esper.get_component(Deformable)}
                assert all(
                    np.allclose(d.body.positions, d.body.rest, atol=1e-9) for _, d in esper.get_component(Deformable)
                )
            seen.append(models)
        # the layers are sheets: the walk reaches SurfaceChainMail, the pack's own model
        assert seen == [{"xpbd"}, {"projective"}, {"surface"}, {"chainmail"}]
    finally:
        app.close()


def test_a_dynamic_body_keeps_moving_toward_its_grab_between_requests():
    app = build_app("chainmail-demo/volume", settings={"model": "xpbd"})
    try:
        with app.active():
            ent, d = esper.get_component(Deformable)[0]
        top = int(np.argmax(d.body.rest[:, 2]))
        from chainsim.systems.tissue.events import GrabRequest

        app.events.emit(GrabRequest(ent, np.array([top]), d.body.rest[top][None] + [0, 0, 2.0], frame="local"))
        gaps = []
        for _ in range(30):
            app.update(app.time.dt)
            gaps.append(float(np.linalg.norm(d.body.positions - d.body.rest, axis=1).sum()))
        assert d.body.positions[top, 2] == pytest.approx(d.body.rest[top, 2] + 2.0)
        assert gaps[-1] > gaps[0] > 0.0  # the rest of the body follows over the next steps
    finally:
        app.close()


def test_auto_picks_the_cheapest_model_meeting_the_budget_and_says_why():
    table = [
        {
            "scene": "block",
            "nodes": 1000,
            "model": "chainmail",
            "setting": "r0",
            "rms_error": 0.2,
            "ms_per_update": 0.1,
        },
        {
            "scene": "block",
            "nodes": 1000,
            "model": "xpbd",
            "setting": "8 substeps",
            "rms_error": 0.04,
            "ms_per_update": 2.0,
        },
        {
            "scene": "block",
            "nodes": 1000,
            "model": "projective",
            "setting": "10 it",
            "rms_error": 0.02,
            "ms_per_update": 5.0,
        },
        {
            "scene": "block",
            "nodes": 8000,
            "model": "xpbd",
            "setting": "8 substeps",
            "rms_error": 0.05,
            "ms_per_update": 20.0,
        },
    ]
    c = choose_model(table, scene="block", nodes=1100, error_budget=0.05)
    assert (c.model, c.setting) == ("xpbd", "8 substeps") and "1000 nodes" in c.reason
    assert choose_model(table, scene="block", nodes=1000, error_budget=0.03).model == "projective"
    assert choose_model(table, scene="block", nodes=1000, time_budget_ms=1.0).model == "chainmail"
    c = choose_model(table, scene="block", nodes=1000, error_budget=0.001, time_budget_ms=3.0)
    assert c.model == "xpbd" and "nothing meets" in c.reason


def test_auto_in_a_pack_reports_its_choice_in_the_summary(tmp_path):
    s = run_pack("chainmail-demo/volume", steps=5, settings={"model": "auto"}, out=str(tmp_path))
    (body,) = s["models"].values()
    assert body["model"] in ("chainmail", "xpbd", "projective", "hybrid")
    assert body["why"].startswith("auto:")


def test_auto_names_its_choice_and_reason_in_the_hud():
    from chainsim.components.hud import HudState

    app = build_app("chainmail-demo/volume", settings={"model": "auto"})
    try:
        app.update(app.time.dt)
        texts = [t for t, _ in app.resource(HudState).messages]
        with app.active():
            ((_, d),) = esper.get_component(Deformable)
        assert any(f": {d.body.model_used} - auto: {d.body.model_used}" in t and "study scene" in t for t in texts), (
            texts
        )
    finally:
        app.close()


def test_the_cutting_panel_says_why_auto_chose_its_model():
    from chainsim.components.hud import HudState

    app = build_app("cutting", settings={"model": "auto"})
    try:
        for _ in range(3):
            app.update(app.time.dt)
        panel = app.resource(HudState).panel_text
        assert any(line.startswith("Tissue model:") for line in panel), panel
        assert any(line.startswith("auto:") for line in panel), panel
    finally:
        app.close()


def test_a_model_switch_is_said_in_the_hud():
    from chainsim.components.hud import HudState

    app = build_app("chainmail-demo/volume", settings={"model": "chainmail"})
    try:
        app.resource(PendingInput).push(app.time.sim_time, Widget("model", True))
        for _ in range(2):
            app.update(app.time.dt)
        assert any(t.startswith("Tissue model: xpbd") for t, _ in app.resource(HudState).messages)
    finally:
        app.close()


def test_projective_solver_settings_come_from_the_pack(tmp_path):
    """A pack picks the projective global step (cg or direct) and its iteration counts in data."""
    import shutil

    dst = tmp_path / "demo"
    shutil.copytree(ASSETS_DIR / "chainmail-demo", dst)
    text = (dst / "pack.toml").read_text()
    head = "[entities.volume.deformable]\ndrag = true\n"
    assert head in text
    extra = 'model = "projective"\nsolver = "cg"\ncg_iterations = 7\nrotation_iterations = 2\n'
    (dst / "pack.toml").write_text(text.replace(head, head + extra))
    app = build_app(f"{dst}/volume")
    try:
        with app.active():
            ((_, d),) = esper.get_component(Deformable)
        assert (
            d.body.model_body.model,
            d.body.model_body.solver,
            d.body.model_body.cg_iterations,
            d.body.model_body.rotation_iterations,
        ) == (
            "projective",
            "cg",
            7,
            2,
        )
    finally:
        app.close()
    (dst / "pack.toml").write_text(text.replace(head, head + 'model = "projective"\nsolver = "lu"\n'))
    from chainsim.game.packs import pack as packs

    _, problems = packs.validate(dst)
    assert any("solver" in str(p) and "direct" in str(p) for p in problems), problems

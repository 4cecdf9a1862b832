"""The cutting trainer pack (thesis 4.5.2) played through its own input scripts: a forceps pull on the
free corner, and a scissors cut across the top layer followed by opening one flap."""

from __future__ import annotations

import json
import math
from pathlib import Path

import esper
import numpy as np
import pytest

from chainsim.components.digest import world_digest
from chainsim.components.resources import Assessment, EntityIndex, PendingInput, Settings
from chainsim.game.packs import pack as packs
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script
from chainsim.systems.tissue.deformable import Deformable

PACK = Path(__file__).resolve().parents[2] / "assets" / "cutting"
SCRIPTS = PACK / "scripts"
CUT_X = 0.6  # the cut-and-open script cuts along x = 0.6 mm, from y = +30 to y = -30
CORNER = (40.0, 30.0, 0.0)


def play(script: str, steps: int | None = None, relax: int | None = None):
    app = build_app("cutting")
    if relax is not None:
        with app.active():
            for _, d in esper.get_component(Deformable):
                d.body.relax_iterations = relax
    app.resource(PendingInput).extend(load_script(SCRIPTS / script))
    n = int(steps if steps is not None else app.resource(Settings).get("steps"))
    for _ in range(n):
        app.update(app.time.dt)
    return app


def layer(app, name: str) -> Deformable:
    with app.active():
        return esper.component_for_entity(app.resource(EntityIndex)[name], Deformable)


def nearest(d: Deformable, point) -> int:
    return int(np.argmin(np.sum((d.body.rest - np.asarray(point)) ** 2, axis=1)))


def box_violation(d: Deformable) -> np.ndarray:
    """How far (mm) each live link lies outside its ChainMail box (thesis 5.2.2: per axis, the rest
    offset scaled by alpha_min..alpha_max, widened by beta times the offset on the other axes)."""
    links = d.body.graph.links[d.body.alive]
    r = d.body.rest[links[:, 1]] - d.body.rest[links[:, 0]]
    p = (
        np.asarray(d.body.positions, dtype=np.float64)[links[:, 1]]
        - np.asarray(d.body.positions, dtype=np.float64)[links[:, 0]]
    )
    amin, amax, beta = d.body.limits[0][d.body.alive], d.body.limits[1][d.body.alive], d.body.limits[2][d.body.alive]
    worst = np.zeros(len(links))
    for a in range(3):
        other = np.abs(r).sum(axis=1) - np.abs(r[:, a])
        lo = np.where(r[:, a] >= 0, amin * r[:, a], amax * r[:, a]) - beta * other
        hi = np.where(r[:, a] >= 0, amax * r[:, a], amin * r[:, a]) + beta * other
        worst = np.maximum(worst, np.maximum(lo - p[:, a], p[:, a] - hi))
    return np.maximum(worst, 0.0)


@pytest.fixture(scope="module")
def pulled():
    app = play("pull-corner.toml")
    yield app
    app.close()


@pytest.fixture(scope="module")
def opened():
    app = play("cut-and-open.toml")
    yield app
    app.close()


# -- the pack ----------------------------------------------------------------------------------------


def test_pack_validates_and_names_the_cutting_procedure():
    pack, problems = packs.validate(PACK)
    assert problems == []
    assert pack.manifest["pack"]["procedure"] == "cutting"
    assert set(pack.scene_names()) == {"trainer", "single"}
    assert [s["id"] for s in pack.section("steps")] == ["pull", "cut", "open"]


def test_meshes_are_what_the_generator_writes():
    from chainsim.game.packbuild.cutting.make_cutting_pack import main

    assert main(["--check"]) == 0


def test_two_layers_with_one_fixed_edge_each(pulled):
    top, low = layer(pulled, "dura"), layer(pulled, "arachnoid")
    for d in (top, low):
        assert 1000 <= d.body.n <= 3000
        span = d.body.rest.max(axis=0) - d.body.rest.min(axis=0)
        assert span[:2] == pytest.approx([80.0, 60.0], abs=1e-3)
        # exactly the elements on the y = -30 mm edge are fixed
        assert np.array_equal(d.body.fixed, np.isclose(d.body.rest[:, 1], -30.0, atol=1e-3))
    assert float(top.body.rest[:, 2].mean() - low.body.rest[:, 2].mean()) == pytest.approx(2.5, abs=1e-6)


# -- pull-corner.toml ----------------------------------------------------------------------------------


def test_pull_moves_the_corner_to_its_target(pulled):
    d = layer(pulled, "dura")
    c = nearest(d, CORNER)
    assert np.allclose(d.body.positions[c], [40.0, 30.0, 20.0], atol=1e-9)
    v = pulled.resource(Assessment).values
    assert v["max_displacement_mm"] == pytest.approx(20.0, abs=1e-9)
    assert "pull" in v["steps_done"]
    assert [u["tool"] for u in v["tool_uses"]] == ["forceps"]


def test_pull_leaves_the_fixed_edge_and_the_lower_layer_alone(pulled):
    d = layer(pulled, "dura")
    moved = np.linalg.norm(d.body.positions - d.body.rest, axis=1) > 1e-9
    assert moved.sum() > 100  # the pull spread well beyond the corner
    assert np.array_equal(d.body.positions[d.body.fixed], d.body.rest[d.body.fixed])
    low = layer(pulled, "arachnoid")
    assert np.array_equal(low.body.positions, low.body.rest)
    v = pulled.resource(Assessment).values
    assert v["elements_moved"] == int((np.linalg.norm(d.body.positions - d.body.rest, axis=1) > 0.01).sum())


def test_the_straight_lift_stretches_no_link_beyond_alpha_max(pulled):
    d = layer(pulled, "dura")
    links = d.body.graph.links[d.body.alive]
    ratio = np.linalg.norm(d.body.positions[links[:, 1]] - d.body.positions[links[:, 0]], axis=1) / np.linalg.norm(
        d.body.rest[links[:, 1]] - d.body.rest[links[:, 0]], axis=1
    )
    assert ratio.max() > 1.05  # the pull did stretch the tissue
    assert ratio.max() <= d.body.limits[1].max() + 1e-9
    assert pulled.resource(Assessment).values["max_stretch_ratio"] == pytest.approx(ratio.max())


@pytest.mark.parametrize("script", ["pull-corner.toml", "cut-and-open.toml"])
def test_the_chainmail_step_keeps_every_link_within_its_limits(script):
    """The deformation itself (relaxation switched off) leaves every live link of the moved layer inside
    its limits: SurfaceChainMail's in-plane box and normal limit (thesis 4.4, the layers' model), or
    the 5.2.3 box relative to rest under volume ChainMail."""
    app = play(script, relax=0)
    try:
        d = layer(app, "dura")
        assert (np.linalg.norm(d.body.positions - d.body.rest, axis=1) > 1e-9).sum() > 100
        if d.body.model_used == "surface":
            in_plane, normal = d.body.model_body.link_excess()
            assert in_plane <= 1e-9 and normal <= 1e-9
        else:
            assert float(box_violation(d).max()) <= 1e-9
        assert np.allclose(d.body.positions[nearest(d, CORNER)], pulled_target(script), atol=1e-9)
    finally:
        app.close()


def pulled_target(script: str):
    return [40.0, 30.0, 20.0] if script == "pull-corner.toml" else [36.0, 24.0, 16.0]


# -- cut-and-open.toml ---------------------------------------------------------------------------------


def crossing(d: Deformable, inner: float = 30.0 + 1e-6) -> np.ndarray:
    """Links whose rest segment crosses the line x = CUT_X at |y| < inner (the path's ends included)."""
    a, b = d.body.rest[d.body.graph.links[:, 0]], d.body.rest[d.body.graph.links[:, 1]]
    sa, sb = a[:, 0] - CUT_X, b[:, 0] - CUT_X
    cross = sa * sb < 0
    t = np.where(cross, sa / np.where(cross, sa - sb, 1.0), 0.0)
    y = a[:, 1] + t * (b[:, 1] - a[:, 1])
    return cross & (np.abs(y) < inner)


def test_cut_removes_the_crossed_links_of_the_top_layer_only(opened):
    d = layer(opened, "dura")
    dead = ~d.body.alive
    assert dead.sum() > 20
    assert np.all(crossing(d)[dead])  # nothing off the path was cut
    assert np.all(dead[crossing(d, inner=29.0)])  # and the path cut through
    low = layer(opened, "arachnoid")
    assert low.body.alive.all()
    assert np.array_equal(low.body.positions, low.body.rest)


def test_the_flap_opens_and_the_other_side_stays(opened):
    d = layer(opened, "dura")
    c = nearest(d, CORNER)
    assert np.allclose(d.body.positions[c], [36.0, 24.0, 16.0], atol=1e-9)
    right = d.body.rest[:, 0] > CUT_X
    moved = np.linalg.norm(d.body.positions - d.body.rest, axis=1) > 1e-9
    assert moved[right].sum() > 100
    assert not moved[~right].any()  # across the cut nothing followed the flap


def test_the_two_sides_are_joined_only_through_the_fixed_edge(opened):
    d = layer(opened, "dura")
    g = d.body.graph
    seen = np.zeros(d.body.n, dtype=bool)
    start = nearest(d, CORNER)
    seen[start] = True
    todo = [start]
    while todo:
        e = todo.pop()
        for j in range(g.indptr[e], g.indptr[e + 1]):
            n = g.indices[j]
            if g.alive[g.link[j]] and not seen[n] and not d.body.fixed[n]:
                seen[n] = True
                todo.append(n)
    assert seen[d.body.rest[:, 0] > CUT_X + 2.0].mean() > 0.95
    assert not seen[d.body.rest[:, 0] < CUT_X].any()


def test_cut_assessment(opened):
    v = opened.resource(Assessment).values
    d = layer(opened, "dura")
    assert v["links_cut"] == int((~d.body.alive).sum())
    assert v["links_cut_by_layer"] == {"dura": v["links_cut"], "arachnoid": 0}
    assert v["layers_cut"] == ["dura"]
    assert v["top_layer"] == "dura"
    assert v["cut_length_mm"] == pytest.approx(60.0, abs=1e-6)
    assert sorted(v["steps_done"]) == ["cut", "open", "pull"]
    assert v["step"] == "done"
    assert [u["tool"] for u in v["tool_uses"]] == ["scissors", "forceps"]
    dt = opened.time.dt
    assert v["scissors_time_s"] == pytest.approx(0.8, abs=dt)  # first touch at 0.2 s, forceps chosen at 1.0 s
    assert v["forceps_time_s"] == pytest.approx(1.3, abs=dt)  # grip at 1.1 s, let go at 2.4 s
    assert v["tool_uses"][1]["duration_s"] == pytest.approx(v["forceps_time_s"])


def test_no_nan_anywhere(pulled, opened):
    for app in (pulled, opened):
        for name in ("dura", "arachnoid"):
            assert np.isfinite(layer(app, name).body.positions).all()
        json.dumps(app.resource(Assessment).values, allow_nan=False)
        assert all(math.isfinite(x) for x in (app.resource(Assessment).values["max_stretch_ratio"],))


def test_cut_and_open_is_deterministic(opened):
    again = play("cut-and-open.toml")
    try:
        assert world_digest(again) == world_digest(opened)
        # the same figures; only the record id each run's Save was given differs
        same = [{k: v for k, v in a.resource(Assessment).values.items() if k != "saved"} for a in (again, opened)]
        assert same[0] == same[1]
    finally:
        again.close()


def test_headless_cli_run_reports_the_cut(cli, tmp_path):
    code, out, err = cli("run", "cutting", "--headless", "--input", SCRIPTS / "cut-and-open.toml", "--out", tmp_path)
    assert code == 0, err
    summary = json.loads((tmp_path / "summary.json").read_text())
    a = summary["assessment"]
    assert a["links_cut"] > 20 and a["layers_cut"] == ["dura"]
    assert a["cut_length_mm"] == pytest.approx(60.0, abs=1e-6)


def test_the_scripted_attempt_is_saved_with_the_cutting_metrics(cli, tmp_path):
    db = tmp_path / "r.sqlite3"
    script = SCRIPTS / "cut-and-open.toml"
    code, _, err = cli(
        "run", "cutting", "--headless", "--input", script, "--db", db, "--class", "c1", "--trainee", "ann"
    )
    assert code == 0, err
    code, out, err = cli("records", "--db", db, "show", "1")
    assert code == 0, err
    fields = dict(line.split(None, 1) for line in out.splitlines() if line.strip())
    assert fields["pack"].strip() == "cutting" and fields["trainee"].strip() == "ann"
    assert fields["target"].strip() == "dura"  # every step done: the opening is made in the top layer
    metrics = json.loads(fields["metrics"])
    assert metrics["links_cut"] > 0 and metrics["layers_cut"] == 1  # the top layer only
    assert metrics["cut_length_mm"] == pytest.approx(60.0)
    assert metrics["scissors_time_s"] > 0 and metrics["forceps_time_s"] > 0
    steps = json.loads(fields["step_times"])
    assert set(steps) == {"pull", "cut", "open"}
    assert float(fields["duration_s"]) >= max(steps.values())


def test_a_second_save_stores_nothing_and_reset_begins_the_next_attempt(tmp_path):
    from chainsim.components.input_events import Widget
    from chainsim.game.records.store import RecordStore

    db = tmp_path / "r.sqlite3"
    app = build_app("cutting", settings={"db": str(db), "class": "c1", "trainee": "ann"})
    try:
        pending = app.resource(PendingInput)
        pending.extend(load_script(SCRIPTS / "cut-and-open.toml"))
        pending.extend(
            [(2.7, Widget("save")), (2.8, Widget("reset")), (2.9, Widget("scissors")), (3.2, Widget("save"))]
        )
        app.run_steps(int(3.4 / app.time.dt))
        values = app.resource(Assessment).values
    finally:
        app.close()
    with RecordStore(db) as store:
        rows = store.list_attempts("c1", "ann")
    assert len(rows) == 2 and values["attempt"] == 2
    assert rows[0]["target"] == "dura" and rows[1]["target"] == "none"  # the second attempt cut nothing
    assert rows[1]["metrics"]["links_cut"] == 0
    assert rows[1]["duration_s"] == pytest.approx(0.4, abs=0.02)  # from the Reset to its Save

"""SurfaceChainMail through the body API (thesis 4.4) and in the cutting trainer's layers (4.5): the normal
band kernel against a plain reference, the links' limits after moves, and the trainer's lift, cut and flap."""

from __future__ import annotations

import esper
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.components.resources import EntityIndex, PendingInput
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script
from chainsim.systems.engine.bodies.factory import make_body
from chainsim.systems.engine.bodies.surface import clamp_pass
from chainsim.systems.engine.kernels.graph import build_graph
from chainsim.systems.engine.meshgen import links_from_cells, triangulated_grid
from chainsim.systems.tissue.deformable import Deformable, use_model
from tests.packs.test_cutting import CORNER, CUT_X, SCRIPTS, nearest


def _plain_band(disp, links, alive, lim, sources, values, pinned):
    """min over sources of value + shortest distance (Floyd-Warshall), then clamp: the band of 4.4.2."""
    n = len(disp)
    d = np.full((n, n), np.inf)
    np.fill_diagonal(d, 0.0)
    for (a, b), ok, w in zip(links, alive, lim):
        if ok and not pinned[a] and not pinned[b]:
            d[a, b] = d[b, a] = min(d[a, b], w)
    for k in range(n):
        d = np.minimum(d, d[:, k : k + 1] + d[k : k + 1, :])
    hi = np.min(values[:, None] + d[sources], axis=0)
    lo = np.max(values[:, None] - d[sources], axis=0)
    out = np.where(pinned, disp, np.minimum(np.maximum(disp, lo), hi))
    out[sources] = values
    return out


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_the_normal_band_matches_a_plain_reference(seed):
    rng = np.random.default_rng(seed)
    _, tris, _ = triangulated_grid(4, 3)
    links = links_from_cells(tris)
    g = build_graph(12, links)
    alive = rng.random(g.n_links) > 0.2

    lim = rng.uniform(0.1, 1.0, g.n_links)
    disp = np.zeros(12)
    src = np.array([int(rng.integers(12))])
    val = np.array([rng.uniform(-3, 3)])
    pinned = np.zeros(12, bool)
    want = _plain_band(disp, g.links, alive, lim, src, val, pinned)
    got = disp.copy()
    args = (g.indptr, g.indices, g.link, alive, lim, src, val, pinned)
    clamp_pass(got, *args, 1.0)
    clamp_pass(got, *args, -1.0)
    np.testing.assert_allclose(got, want, atol=1e-12)


def test_moves_keep_every_link_within_its_limits():
    rest, tris, _ = triangulated_grid(12, 10, dim=3)
    rest = np.asarray(rest, float)
    fixed = rest[:, 1] <= rest[:, 1].min() + 1e-9
    b = make_body("surface", rest, triangles=tris, fixed=fixed, alpha_min=0.7, alpha_max=1.6, beta=0.35, exact=True)
    rng = np.random.default_rng(1)
    for _ in range(20):
        e = int(rng.integers(len(rest)))
        b.grab([e], rest[e] + rng.uniform(-2, 2, 3))
        b.step()
        plane, normal = b.link_excess()
        assert plane <= 1e-9 and normal <= 1e-9
    assert not np.any(b.positions[fixed] != rest[fixed])


def _play(script: str):
    app = build_app("cutting")
    with app.active():
        for _e, d in esper.get_component(Deformable):
            use_model(d, "surface")
    app.resource(PendingInput).extend(load_script(SCRIPTS / script))
    for _ in range(360):
        app.update(app.time.dt)
    return app


def _layer(app, name):
    with app.active():
        return esper.component_for_entity(app.resource(EntityIndex)[name], Deformable)


@pytest.mark.parametrize("script,target", [("pull-corner.toml", [40, 30, 20]), ("cut-and-open.toml", [36, 24, 16])])
def test_the_cutting_trainer_lifts_cuts_and_opens_on_surface_chainmail(script, target):
    app = _play(script)
    try:
        d = _layer(app, "dura")
        assert d.body.model_used == "surface"
        c = nearest(d, CORNER)
        np.testing.assert_allclose(d.body.positions[c], target, atol=1e-9)
        assert max(d.body.model_body.link_excess()) <= 1e-9
        moved = np.linalg.norm(d.body.positions - d.body.rest, axis=1) > 1e-9
        assert moved.sum() > 100 and not moved[d.body.fixed].any()
        low = _layer(app, "arachnoid")
        assert np.array_equal(low.body.positions, low.body.rest) and low.body.alive.all()
        if script == "cut-and-open.toml":
            assert (~d.body.alive).sum() > 20
            assert not moved[d.body.rest[:, 0] < CUT_X].any()  # across the cut nothing followed the flap
    finally:
        app.close()

"""The soft body a scene holds: readers see the model body's positions, links and limits through it, the
moved ids reach the renderer once each, and its limits follow links added at run time."""

from __future__ import annotations

import numpy as np

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.bodies.chainmail import ChainMailBody, link_limits
from chainsim.systems.engine.bodies.soft import SoftBody
from chainsim.systems.engine.kernels.graph import build_graph
from chainsim.systems.engine.meshes import MeshData


def _sheet(n: int = 5) -> SoftBody:
    pos, tris, _ = meshgen.triangulated_grid(n, n, 1.0, dim=3)
    rest = np.asarray(pos, dtype=np.float64)
    tris = np.asarray(tris, dtype=np.int64)
    links = meshgen.links_from_polygons(tris)
    limits = link_limits(len(links), 0.8, 1.2, 0.1)
    fixed = np.zeros(len(rest), dtype=np.bool_)
    soft = SoftBody(rest, MeshData(rest, tris), links, fixed, limits, relax_iterations=0, exact=False)
    body = ChainMailBody(rest, build_graph(len(rest), links), *limits)
    soft.adopt(body, "chainmail", "chainmail (as the pack asks)")
    return soft


def test_readers_see_the_model_bodys_own_arrays():
    soft = _sheet()
    body = soft.model_body
    assert soft.positions is body.positions and soft.graph is body.graph and soft.alive is body.graph.alive
    body.move([12], [[2.0, 2.0, 3.0]])
    np.testing.assert_allclose(soft.positions[12], [2.0, 2.0, 3.0])
    assert soft.last_order[0] == 12 and soft.last_shortfall == 0.0


def test_moved_ids_reach_the_renderer_once_each_until_taken():
    soft = _sheet()
    soft.changed(np.array([3, 1, 3]))
    soft.mark_dirty(np.array([1, 7]))
    assert soft.dirty.tolist() == [1, 3, 7] and soft.version == 1
    assert soft.take_dirty().tolist() == [1, 3, 7]
    assert len(soft.dirty) == 0 and len(soft.take_dirty()) == 0
    soft.mark_dirty(np.array([3]))  # taken ids are marked again when they move again
    assert soft.dirty.tolist() == [3]
    soft.changed()  # the whole body (a model switch, a reset)
    assert sorted(soft.take_dirty().tolist()) == list(range(soft.n)) and soft.version == 2


def test_limits_follow_links_added_at_run_time_and_new_bodies_start_from_the_spawn_ones():
    soft = _sheet()
    m = len(soft.links)
    assert all(a is b for a, b in zip(soft.limits, soft.base_limits))
    assert soft.model_body.add_links([[0, 24]]) == 1
    amin, amax, beta = soft.limits
    assert len(amin) == m + 1 and (amin[-1], amax[-1], beta[-1]) == (0.8, 1.2, 0.1)
    assert len(soft.base_limits[0]) == m  # the links a new ChainMail body is built on

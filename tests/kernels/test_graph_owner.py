"""The Graph as the one owner of per-link data: its CSR-entry copies (alive flags, materials) never drift
from the link-order data, whatever sequence of cuts, revivals, link additions and material changes a
body goes through, and nothing outside it can write either copy."""

from __future__ import annotations

import numpy as np
import pytest
from cascade_reference import random_mesh
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.kernels import topology
from chainsim.systems.engine.kernels.chainmail import material_arrays
from chainsim.systems.engine.kernels.graph import build_graph


def assert_in_step(graph):
    np.testing.assert_array_equal(graph.entry_alive, graph.alive[graph.link])
    if graph.amin is not None:
        for per_link, per_entry in (
            (graph.amin, graph.entry_amin),
            (graph.amax, graph.entry_amax),
            (graph.beta, graph.entry_beta),
        ):
            got = per_entry[np.arange(len(graph.link)) * graph.mat_stride]
            np.testing.assert_array_equal(got, per_link[graph.link])


ops = st.lists(
    st.tuples(st.sampled_from(["cut", "revive_some", "revive", "add", "materials", "uniform"]), st.integers(0, 2**31)),
    max_size=12,
)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31), st.sampled_from(["planar", "surface", "volume", "random"]), ops)
def test_entry_copies_follow_every_change(seed, kind, steps):
    rng = np.random.default_rng(seed)
    dim = {"planar": 2}.get(kind, 3)
    rest, links = random_mesh(kind, dim, rng, size=4)
    n = len(rest)
    graph = build_graph(n, links)
    graph.bind_materials(*material_arrays(graph.n_links, 0.8, 1.2, 0.1))
    assert graph.mat_stride == 0  # one material for every link: one value each
    assert_in_step(graph)
    for op, s in steps:
        r = np.random.default_rng(s)
        m = graph.n_links
        if op == "cut" and m:
            killed = graph.cut(r.choice(m, size=int(r.integers(1, m + 1)), replace=True))
            assert not graph.alive[killed].any()
        elif op == "revive_some" and m:
            graph.set_alive(r.random(m) < 0.5, True)
        elif op == "revive":
            graph.revive()
            assert graph.alive.all()
        elif op == "add":
            a = r.integers(0, n, size=4)
            b = (a + r.integers(1, n, size=4)) % n
            old = graph
            graph = topology.add_links(graph, np.stack([a, b], 1))
            np.testing.assert_array_equal(graph.alive[: old.n_links], old.alive)
            graph.bind_materials(*material_arrays(graph.n_links, r.uniform(0, 1, graph.n_links), 1.5, 0.2))
        elif op == "materials":
            graph.bind_materials(*material_arrays(m, r.uniform(0, 1, m), r.uniform(1, 2, m), r.uniform(0, 0.5, m)))
            assert graph.mat_stride == (1 if m > 1 else graph.mat_stride)
        elif op == "uniform":
            graph.bind_materials(*material_arrays(m, 0.5, 2.0, 0.3))
        assert_in_step(graph)


def test_nothing_outside_the_graph_can_write_its_data():
    rest, links = random_mesh("surface", 3, np.random.default_rng(1), size=4)
    graph = build_graph(len(rest), links)
    mats = material_arrays(graph.n_links, 0.8, 1.2, 0.1)
    graph.bind_materials(*mats)
    for arr in (graph.alive, graph.entry_alive, graph.indices, graph.indptr, graph.link, graph.links, *mats):
        with pytest.raises(ValueError, match="read-only"):
            arr[0] = arr[0]
    links_given = np.array(links)
    build_graph(len(rest), links_given)
    links_given[0, 0] = links_given[0, 0]  # the caller's own array stays writeable (the graph copies it)


def test_cutting_through_topology_updates_both_orders():
    rest, _, links = meshgen.triangulated_grid(6, 6, dim=3)
    graph = build_graph(len(rest), links)
    killed = topology.cut_segment(rest, graph, [2.5, -1.0, 0.0], [2.5, 7.0, 0.0])
    assert len(killed) and not graph.alive[killed].any()
    assert_in_step(graph)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_dead_link_count_follows_every_change_of_the_alive_flags(seed):
    """n_dead (which lets the breadth-first cascade skip the alive flags) equals the cut links after any
    sequence of cuts, revivals of single links and whole resets."""
    rng = np.random.default_rng(seed)
    rest, links = random_mesh("volume", 3, rng, size=4)
    alive = rng.random(len(links)) > 0.3
    graph = build_graph(len(rest), links, alive=alive)
    assert graph.n_dead == int((~graph.alive).sum())
    for _ in range(6):
        ids = rng.choice(len(links), int(rng.integers(1, 8)))
        if rng.random() < 0.15:
            graph.revive()
        elif rng.random() < 0.5:
            graph.cut(ids)
        else:
            graph.set_alive(ids, True)
        assert graph.n_dead == int((~graph.alive).sum())

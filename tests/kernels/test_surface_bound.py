"""SurfaceChainMail's normal band bound (bodies.surface.bound_from) against scipy's Dijkstra on random graphs."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse.csgraph import dijkstra

from chainsim.systems.engine.bodies.surface import bound_from
from chainsim.systems.engine.kernels.graph import build_graph


@st.composite
def graphs(draw):
    n = draw(st.integers(2, 25))
    pairs = draw(st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)), min_size=1, max_size=60))
    links = np.array([(a, b) for a, b in pairs if a != b] or [(0, 1)], dtype=np.int64)
    lim = np.array(draw(st.lists(st.floats(0.01, 5.0), min_size=len(links), max_size=len(links))))
    alive = np.array(draw(st.lists(st.booleans(), min_size=len(links), max_size=len(links))))
    k = draw(st.integers(1, n))
    sources = np.array(draw(st.lists(st.integers(0, n - 1), min_size=k, max_size=k)), dtype=np.int64)
    values = np.array(draw(st.lists(st.floats(-10, 10), min_size=k, max_size=k)))
    return n, links, lim, alive, sources, values


@settings(max_examples=80, deadline=None)
@given(graphs())
def test_bound_is_the_least_value_plus_distance_over_live_links(g):
    n, links, lim, alive, sources, values = g
    graph = build_graph(n, links)
    got = bound_from(graph.indptr, graph.indices, graph.link, alive, lim, sources, values)
    # reference: one Dijkstra per source over the live links (the shortest of duplicated links counts)
    w = np.full((n, n), np.inf)
    for (a, b), length, live in zip(links, lim, alive):
        if live:
            w[a, b] = w[b, a] = min(w[a, b], length)
    dense = np.where(np.isfinite(w), w, 0.0)
    dist = dijkstra(sp.csr_matrix(dense), directed=False, indices=sources)
    want = np.min(values[:, None] + dist, axis=0)
    finite = np.isfinite(want)
    assert np.array_equal(np.isfinite(got), finite)
    assert np.allclose(got[finite], want[finite], rtol=1e-12, atol=1e-12)

"""Structured meshes: link sets against plain references, neighbour counts the thesis quotes."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.systems.engine import meshgen


@settings(max_examples=50, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 30), st.integers(0, 30)), max_size=80))
def test_unique_links_matches_a_set_reference(pairs):
    got = meshgen.unique_links(np.array(pairs, dtype=np.int64).reshape(-1, 2))
    want = sorted({(min(a, b), max(a, b)) for a, b in pairs if a != b})
    assert [tuple(r) for r in got.tolist()] == want


def test_grid_has_four_and_six_neighbours():
    pos, links = meshgen.grid((5, 4))
    deg = np.bincount(links.ravel(), minlength=len(pos))
    assert deg.max() == 4 and len(links) == 4 * 4 + 5 * 3
    pos, links = meshgen.grid((3, 3, 3))
    assert np.bincount(links.ravel()).max() == 6
    d = np.linalg.norm(pos[links[:, 0]] - pos[links[:, 1]], axis=1)
    np.testing.assert_allclose(d, 1.0)


def test_non_uniform_grid_uses_given_coordinates():
    xs = np.array([0.0, 1.0, 3.0, 7.0])
    pos, links = meshgen.grid((4, 2), spacing=[xs, np.array([0.0, 2.0])])
    np.testing.assert_array_equal(np.unique(pos[:, 0]), xs)


def test_tet_grid_matches_the_thesis_volume():
    pos, tets, links = meshgen.tet_grid(7, 7, 7)
    assert len(pos) == 343  # thesis 5.3: 343 elements, up to 14 neighbours
    assert np.bincount(links.ravel()).max() == 14
    v = (
        np.einsum(
            "ij,ij->i",
            pos[tets[:, 1]] - pos[tets[:, 0]],
            np.cross(pos[tets[:, 2]] - pos[tets[:, 0]], pos[tets[:, 3]] - pos[tets[:, 0]]),
        )
        / 6
    )
    assert np.isclose(np.abs(v).sum(), 6.0**3)  # the tets fill the block exactly
    assert np.all(np.abs(v) > 0)


def test_random_graph_is_connected():
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    pos, links = meshgen.random_graph(40, 70, 3, np.random.default_rng(1))
    a = coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(40, 40))
    assert connected_components(a, directed=False)[0] == 1

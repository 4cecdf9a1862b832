"""The hybrid body's assembly kernels against scipy on random tetrahedra: pattern, values, pieces."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.sparse.csgraph import connected_components

from chainsim.systems.engine.kernels.twolevel import assemble_tets, tet_components, tet_pattern


@st.composite
def meshes(draw):
    """Random 'tetrahedra' over a few nodes (any four distinct nodes; shared nodes and repeats included),
    random per-element matrices, and a random subset of elements to assemble."""
    n = draw(st.integers(4, 30))
    t = draw(st.integers(1, 40))
    rows = [draw(st.permutations(range(n)).map(lambda p: p[:4])) for _ in range(t)]
    tets = np.array(rows, dtype=np.int64)
    finite = st.floats(-10, 10, allow_nan=False)
    D = draw(arrays(np.float64, (t, 4, 3), elements=finite))
    w = draw(arrays(np.float64, (t,), elements=st.floats(0, 5, allow_nan=False)))
    K_e = draw(arrays(np.float64, (t, 12, 12), elements=finite))
    chosen = draw(arrays(np.bool_, (t,)))
    return n, tets, D, w, K_e, chosen


@settings(max_examples=60, deadline=None)
@given(meshes())
def test_assembly_equals_summing_every_element_matrix(mesh):
    n, tets, D, w, K_e, chosen = mesh
    elems = np.flatnonzero(chosen)
    indptr, indices = tet_pattern(n, tets, elems)
    l_data, k_data = assemble_tets(indptr, indices, tets, elems, D, w, K_e)
    L = sp.csr_matrix((l_data, indices, indptr), shape=(n, n)).toarray()
    K = sp.bsr_matrix((k_data, indices, indptr), shape=(3 * n, 3 * n)).toarray()
    L_ref, K_ref = np.zeros((n, n)), np.zeros((3 * n, 3 * n))
    for e in elems:
        dof = (3 * tets[e][:, None] + np.arange(3)).ravel()
        L_ref[np.ix_(tets[e], tets[e])] += w[e] * D[e] @ D[e].T
        K_ref[np.ix_(dof, dof)] += K_e[e]
    assert np.allclose(L, L_ref, atol=1e-9) and np.allclose(K, K_ref, atol=1e-9)
    # the pattern holds exactly the node pairs that share an assembled element, each row sorted
    pairs = np.zeros((n, n), dtype=bool)
    for e in elems:
        pairs[np.ix_(tets[e], tets[e])] = True
    got = np.zeros((n, n), dtype=bool)
    for a in range(n):
        row = indices[indptr[a] : indptr[a + 1]]
        assert np.all(np.diff(row) > 0)
        got[a, row] = True
    assert np.array_equal(got, pairs)


@settings(max_examples=60, deadline=None)
@given(meshes())
def test_pieces_are_the_connected_components_of_the_live_elements(mesh):
    n, tets, _, _, _, active = mesh
    root = tet_components(n, tets, active)
    t = tets[active]
    adj = sp.csr_matrix(
        (np.ones(16 * len(t)), (np.repeat(t, 4, axis=1).ravel(), np.tile(t, (1, 4)).ravel())), shape=(n, n)
    )
    _, label = connected_components(adj, directed=False)
    # the same partition: two nodes share a representative exactly when they share a component
    assert np.array_equal(root[:, None] == root[None, :], label[:, None] == label[None, :])
    assert np.all(root[root] == root)  # each representative represents itself

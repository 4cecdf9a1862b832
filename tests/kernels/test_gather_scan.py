"""The sixteen-at-a-time scan of unmoved neighbours (kernels.gather) against a plain loop, and the
breadth-first cascade built on it against the waiting-list reference on meshes whose rows are longer
than sixteen entries or list a link twice (the cases where its chunks and its second stamp check
matter), or whose sponsors share most neighbours (where the masks it keeps from its look-ahead go
stale)."""

from __future__ import annotations

import numpy as np
from cascade_reference import ref_cascade
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from numba import njit

from chainsim.systems.engine.kernels.chainmail import (
    _NO_FIXED,
    _NO_ROWS,
    ORDER_BREADTH_FIRST,
    _cascade_fifo,
    cascade,
    make_workspace,
    material_arrays,
)
from chainsim.systems.engine.kernels.gather import LANES, lowest_bit, mask_of
from chainsim.systems.engine.kernels.graph import build_graph

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.sampled_from([np.int32, np.int64]), st.sampled_from([np.int32, np.uint8]))
def test_mask_marks_exactly_the_entries_whose_stamp_differs(seed, id_dtype, stamp_dtype):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 200))
    m = int(rng.integers(1, 100))
    ids = np.zeros(m + LANES, dtype=id_dtype)  # padded as the cascade's CSR copy is
    ids[:m] = rng.integers(0, n, m)
    # byte stamps are read four bytes at a time: three bytes of slack after them, as a Workspace keeps,
    # holding values that must not leak into the comparison
    stamp = rng.integers(0, 256, n + 3).astype(stamp_dtype)[:n] if stamp_dtype == np.uint8 else None
    if stamp is None:
        stamp = rng.integers(0, 3, n).astype(np.int32)
    else:
        stamp[:] = rng.integers(0, 3, n)
    gen = np.int32(rng.integers(0, 3))
    start = int(rng.integers(0, m))
    count = int(rng.integers(0, min(LANES, m - start) + 1))
    want = sum(1 << k for k in range(count) if stamp[ids[start + k]] != gen)
    assert mask_of(ids, start, count, stamp, gen) == want


@njit(cache=True)
def _lowest(x):
    return lowest_bit(x)


@given(st.integers(0, 2**63 - 1))
def test_lowest_bit_is_the_index_of_the_lowest_set_bit(x):
    want = (x & -x).bit_length() - 1 if x else 64
    assert _lowest(np.int64(x)) == want


def hub_mesh(rng, dim):
    """A random graph plus hubs linked to 17-40 elements each, and some links listed twice."""
    n = int(rng.integers(30, 80))
    rest = rng.uniform(-3.0, 3.0, (n, dim))
    links = [tuple(rng.choice(n, 2, replace=False)) for _ in range(2 * n)]
    for hub in rng.choice(n, 3, replace=False):
        for other in rng.choice(n, int(rng.integers(17, min(40, n))), replace=False):
            if other != hub:
                links.append((hub, other))
    links = np.array(links, dtype=np.int64)
    twice = links[rng.choice(len(links), len(links) // 10, replace=False)]
    return rest, np.concatenate([links, twice[:, ::-1]])


@SETTINGS
@given(
    st.integers(0, 2**32 - 1),
    st.integers(1, 3),
    st.sampled_from([np.float64, np.float32]),
    st.booleans(),
    st.booleans(),
)
def test_breadth_first_cascade_on_long_rows_matches_reference(seed, dim, dtype, per_link, features):
    rng = np.random.default_rng(seed)
    rest, links = hub_mesh(rng, dim)
    n, m = len(rest), len(links)
    if per_link:
        mats = (rng.uniform(0.3, 1.0, m), rng.uniform(1.0, 2.0, m), rng.uniform(0.0, 0.4, m))
    else:
        mats = (0.8, 1.2, 0.1)
    amin, amax, beta = material_arrays(m, *mats)
    alive = rng.random(m) > 0.15 if features else np.ones(m, bool)
    fixed = rng.random(n) < 0.1 if features else None
    graph = build_graph(n, links)
    graph.set_alive(~alive, False)
    rest = rest.astype(dtype)
    pos = (rest + rng.normal(scale=0.3, size=rest.shape)).astype(dtype)
    ws = make_workspace(n)
    for _ in range(3):  # a drag: each move from the last one's shape, one workspace
        grab = np.array([int(rng.integers(n))])
        target = (pos[grab] + rng.normal(scale=2.0, size=(1, dim))).astype(dtype)
        want = ref_cascade(rest, pos, links, alive, amin, amax, beta, grab, target, fixed, order=ORDER_BREADTH_FIRST)
        moved, sponsor = cascade(rest, pos, graph, amin, amax, beta, grab, target, fixed=fixed, workspace=ws)
        np.testing.assert_array_equal(moved, want[1])
        np.testing.assert_array_equal(sponsor, want[2])
        np.testing.assert_array_equal(pos, want[0])


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(1, 3), st.sampled_from([np.float64, np.float32]))
def test_masks_kept_from_the_look_ahead_never_move_an_element_twice(seed, dim, dtype):
    """The loop takes a queued sponsor's unmoved-neighbour mask six places before its turn and keeps it for
    that turn. On a dense graph (rows of 8 to 16 entries, so a whole row is one kept mask) most neighbours a
    mask marks are moved by an earlier sponsor in between: those must be skipped, and the result is the
    waiting-list reference's, over a drag of several frames on one workspace."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(40, 160))
    k = int(rng.integers(4, 9))  # about 2k entries a row
    links = np.array([(i, int(j)) for i in range(n) for j in rng.choice(n, k, replace=False) if j != i])
    rest = rng.uniform(-3.0, 3.0, (n, dim)).astype(dtype)
    amin, amax, beta = material_arrays(len(links), *(rng.uniform(0.5, 1.0), rng.uniform(1.0, 1.5), 0.1))
    graph = build_graph(n, links)
    pos = rest.copy()
    ws = make_workspace(n)
    for _ in range(4):
        grab = np.array([int(rng.integers(n))])
        target = (pos[grab] + rng.normal(scale=1.5, size=(1, dim))).astype(dtype)
        want = ref_cascade(rest, pos, links, np.ones(len(links), bool), amin, amax, beta, grab, target)
        moved, sponsor = cascade(rest, pos, graph, amin, amax, beta, grab, target, workspace=ws)
        assert len(np.unique(moved)) == len(moved)
        np.testing.assert_array_equal(moved, want[1])
        np.testing.assert_array_equal(sponsor, want[2])
        np.testing.assert_array_equal(pos, want[0])


@SETTINGS
@given(st.integers(0, 2**32 - 1))
def test_rows_of_sixteen_hold_the_first_fifteen_neighbours_and_mark_the_rows_that_overflow(seed):
    """Workspace.rows16 against a plain construction: each element's row is one 64-byte line holding its
    first fifteen neighbours in CSR order, n in the lanes it does not fill, and in its last lane n + 1
    exactly where it has more than fifteen neighbours."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 60))
    links = rng.integers(0, n, (int(rng.integers(1, 8 * n)), 2))
    links = links[links[:, 0] != links[:, 1]]
    graph = build_graph(n, links)
    rows = make_workspace(n).rows16(graph)
    assert rows.dtype == np.int32 and rows.shape == (LANES * n,) and rows.ctypes.data % 64 == 0
    for i in range(n):
        nbrs = graph.indices[graph.indptr[i] : graph.indptr[i + 1]].tolist()
        want = nbrs[: LANES - 1] + [n] * (LANES - 1 - min(len(nbrs), LANES - 1))
        want.append(n + 1 if len(nbrs) > LANES - 1 else n)
        assert rows[LANES * i : LANES * (i + 1)].tolist() == want


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 2**32 - 1), st.sampled_from([np.float64, np.float32]), st.booleans())
def test_3d_cascade_where_rows_hold_fourteen_to_seventeen_neighbours_matches_reference(seed, dtype, features):
    """Rows just under, at and just over the fifteen lanes a row of sixteen gives neighbours (the rest from
    the CSR lists, after the row), with cut links, anchors and per-link materials or without."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(20, 50))
    links = []
    for i in range(n):
        for j in rng.choice(n, int(rng.integers(7, 10)), replace=False):
            if j != i:
                links.append((i, int(j)))
    links = np.array(links, dtype=np.int64)  # about 14 to 17 neighbours an element once both ends count
    m = len(links)
    rest = rng.uniform(-3.0, 3.0, (n, 3)).astype(dtype)
    per_link = (rng.uniform(0.5, 1.0, m), rng.uniform(1.0, 1.5, m), rng.uniform(0.0, 0.2, m))
    mats = per_link if features else (0.8, 1.2, 0.1)
    amin, amax, beta = material_arrays(m, *mats)
    alive = rng.random(m) > 0.15 if features else np.ones(m, bool)
    fixed = rng.random(n) < 0.1 if features else None
    graph = build_graph(n, links)
    graph.set_alive(~alive, False)
    degrees = np.diff(graph.indptr)
    assert degrees.max() > LANES - 1 >= degrees.min()
    pos = rest.copy()
    ws = make_workspace(n)
    for _ in range(3):
        grab = np.array([int(rng.integers(n))])
        target = (pos[grab] + rng.normal(scale=1.5, size=(1, 3))).astype(dtype)
        want = ref_cascade(rest, pos, links, alive, amin, amax, beta, grab, target, fixed)
        moved, sponsor = cascade(rest, pos, graph, amin, amax, beta, grab, target, fixed=fixed, workspace=ws)
        np.testing.assert_array_equal(moved, want[1])
        np.testing.assert_array_equal(sponsor, want[2])
        np.testing.assert_array_equal(pos, want[0])


def test_a_workspace_reused_past_the_byte_stamps_wrap_keeps_matching_the_reference():
    """Stamps are bytes, so every 253rd cascade on a workspace clears them and starts the generations
    again. A first pull moves every element (stamped with generation 1); 252 holds then move nothing but
    the held element; the pull after the wrap, generation 1 again, must not find the others "moved"."""
    rng = np.random.default_rng(3)
    n = 40
    links = np.array([(i, int(j)) for i in range(n) for j in rng.choice(n, 5, replace=False) if j != i])
    rest = rng.uniform(-3.0, 3.0, (n, 3))
    amin, amax, beta = material_arrays(len(links), 0.8, 1.2, 0.1)
    graph = build_graph(n, links)
    pos = rest.copy()
    ws = make_workspace(n)
    grab = np.array([0])
    for k in range(254):
        target = pos[grab] + (5.0 if k in (0, 253) else 0.0)
        want = ref_cascade(rest, pos, links, np.ones(len(links), bool), amin, amax, beta, grab, target)
        moved, _sponsor = cascade(rest, pos, graph, amin, amax, beta, grab, target, workspace=ws)
        np.testing.assert_array_equal(moved, want[1])
        np.testing.assert_array_equal(pos, want[0])
        if k in (0, 253):
            assert ws.gen == 1 and len(moved) == n  # the whole mesh followed, both times
    assert ws.stamp.dtype == np.uint8


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 2**32 - 1), st.integers(1, 3))
def test_breadth_first_loop_on_int64_lists_matches_reference(seed, dim):
    """Meshes with 2^31 or more CSR entries keep int64 neighbour lists, unpadded: the loop then scans them
    entry by entry, with the same result (run here on a small mesh's own int64 arrays)."""
    rng = np.random.default_rng(seed)
    rest, links = hub_mesh(rng, dim)
    n, m = len(rest), len(links)
    amin, amax, beta = material_arrays(m, rng.uniform(0.3, 1.0, m), rng.uniform(1.0, 2.0, m), 0.1)
    graph = build_graph(n, links)
    graph.cut(rng.choice(m, m // 8, replace=False))
    graph.bind_materials(amin, amax, beta)
    pos = rest + rng.normal(scale=0.3, size=rest.shape)
    grab = np.array([int(rng.integers(n))])
    target = pos[grab] + rng.normal(scale=2.0, size=(1, dim))
    want = ref_cascade(rest, pos, links, graph.alive, amin, amax, beta, grab, target)
    ws = make_workspace(n)
    got = pos.copy()
    indptr, indices, *link_data = graph.kernel_args
    count = _cascade_fifo(
        rest, got, indptr, indices, _NO_ROWS, *link_data, grab, target, _NO_FIXED, False, ws.stamp,
        ws.next_generation(), ws.out_order, ws.out_sponsor, True,
    )  # fmt: skip
    assert graph.indices.dtype == np.int64
    np.testing.assert_array_equal(ws.out_order[:count], want[1])
    np.testing.assert_array_equal(got, want[0])

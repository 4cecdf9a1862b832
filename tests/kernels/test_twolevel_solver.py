"""The hybrid body's solver kernels against plain references on drawn inputs: the block matrix product
and block-preconditioned CG against scipy and numpy, the smallest volume ratio against numpy's
determinants (and the hybrid start's two shortcuts to it, bit for bit), and the drift that a front
node reports against a plain breadth-first search."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from chainsim.systems.engine.kernels.twolevel import (
    block_pcg,
    bspmv3,
    det_at,
    follow_far,
    min_det,
    min_det_below,
    ring_max,
    volume_barrier,
)

finite = st.floats(-10, 10, allow_nan=False)


@st.composite
def spd_blocks(draw):
    """A random symmetric positive definite matrix of 3 x 3 blocks (n blocks a side) with a random block
    pattern, as block CSR, and a right-hand side."""
    n = draw(st.integers(1, 12))
    keep = draw(arrays(np.bool_, (n, n))) | np.eye(n, dtype=bool)
    # entries of C within 1: a condition number CG in round-off solves in as many steps as unknowns
    C = draw(arrays(np.float64, (3 * n, 3 * n), elements=st.floats(-1, 1, allow_nan=False)))
    C = np.where(np.kron(keep, np.ones((3, 3), dtype=bool)), C, 0.0)  # zero blocks: a sparse pattern
    M = C @ C.T + np.eye(3 * n)  # symmetric positive definite
    b = draw(arrays(np.float64, (n, 3), elements=finite))
    return M, b


def _bsr(M):
    B = sp.csr_matrix(M).tobsr(blocksize=(3, 3))
    B.sort_indices()
    return B.indptr.astype(np.int64), B.indices.astype(np.int64), np.ascontiguousarray(B.data)


@settings(max_examples=60, deadline=None)
@given(spd_blocks())
def test_block_product_matches_the_dense_product(case):
    M, b = case
    out = np.full_like(b, np.nan)
    bspmv3(*_bsr(M), b, out)
    np.testing.assert_allclose(out.ravel(), M @ b.ravel(), rtol=1e-10, atol=1e-10 * max(1.0, np.abs(M).max()))


@settings(max_examples=60, deadline=None)
@given(spd_blocks(), st.integers(1, 40))
def test_block_pcg_reduces_the_energy_norm_error_and_solves_with_enough_steps(case, steps):
    M, b = case
    n = len(b)
    indptr, indices, blocks = _bsr(M)
    inv = np.linalg.inv(np.stack([M[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] for i in range(n)]))
    x = np.full_like(b, np.nan)  # overwritten: the solve starts from zero
    scratch = [np.zeros_like(b) for _ in range(4)]
    block_pcg(indptr, indices, blocks, inv, b, x, steps, *scratch)
    exact = np.linalg.solve(M, b.ravel())
    err = x.ravel() - exact

    def energy_norm(e):
        return float(e @ M @ e)

    # CG from zero never leaves the error larger (in K's norm) than the zero start's, and with as many
    # steps as unknowns it solves (round-off aside)
    assert energy_norm(err) <= energy_norm(exact) * (1 + 1e-9) + 1e-12
    if steps >= 3 * n:  # round-off on ill-conditioned draws: measured in the energy norm
        assert energy_norm(err) <= 1e-6 * energy_norm(exact) + 1e-20


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 30))
def test_min_det_is_the_smallest_volume_ratio(seed, count):
    rng = np.random.default_rng(seed)
    rest = rng.normal(size=(count * 4, 3))
    tets = np.arange(count * 4, dtype=np.int64).reshape(count, 4)
    x = rest + 0.5 * rng.normal(size=rest.shape)  # inverted elements included
    Dm = np.stack([np.stack([rest[t[k]] - rest[t[0]] for k in (1, 2, 3)], axis=1) for t in tets])
    inv = np.linalg.inv(Dm)
    D = np.zeros((count, 4, 3))
    D[:, 1:, :] = inv
    D[:, 0, :] = -inv.sum(axis=1)
    elems = np.flatnonzero(rng.random(count) < 0.7)
    if len(elems) == 0:
        elems = np.array([0], dtype=np.int64)
    ref = min(
        np.linalg.det(np.stack([x[t[k]] - x[t[0]] for k in (1, 2, 3)], axis=1)) / np.linalg.det(Dm[e])
        for e, t in zip(elems, tets[elems])
    )
    assert min_det(x, tets, D, elems) == pytest.approx(ref, rel=1e-9, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 30), st.floats(-1.0, 1.5))
def test_the_starts_ratios_are_min_dets_own_bits(seed, count, floor):
    """The hybrid body's start decides with these what min_det would decide: one element's ratio is the
    very number min_det gives it, and min_det_below's smallest is min_det's, its index the first below."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(count * 4, 3)) * rng.choice([1e-3, 1.0, 1e3])
    tets = rng.permutation(count * 4).astype(np.int64).reshape(count, 4)
    D = rng.normal(size=(count, 4, 3)) * rng.choice([1e-2, 1.0, 1e2])
    ratios = [min_det(x, tets, D, np.array([t])) for t in range(count)]
    assert [np.float64(det_at(x, tets, D, t)).tobytes() for t in range(count)] == [
        np.float64(j).tobytes() for j in ratios
    ]
    elems = rng.permutation(count)[: max(1, count // 2)].astype(np.int64)
    smallest, below = min_det_below(x, tets, D, elems, floor)
    assert np.float64(smallest).tobytes() == np.float64(min_det(x, tets, D, elems)).tobytes()
    first = next((k for k, t in enumerate(elems) if ratios[t] < floor), -1)
    assert below == first


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(0, 4))
def test_ring_max_is_the_largest_value_within_the_rings_among_the_listed_nodes(seed, passes):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 40))
    A = rng.random((n, n)) < 0.1
    A = A | A.T
    np.fill_diagonal(A, False)
    G = sp.csr_matrix(A)
    indptr, indices = G.indptr.astype(np.int64), G.indices.astype(np.int64)
    nodes = np.flatnonzero(rng.random(n) < 0.6).astype(np.int64)
    values = rng.random(n)
    got = ring_max(indptr, indices, nodes, values, passes)
    inside = np.zeros(n, dtype=bool)
    inside[nodes] = True
    want = values.copy()
    for i in nodes:  # breadth-first within the listed nodes, `passes` rings out
        seen, ring = {i}, {i}
        for _ in range(passes):
            ring = {j for a in ring for j in indices[indptr[a] : indptr[a + 1]] if inside[j]} - seen
            seen |= ring
        want[i] = max(values[j] for j in seen)
    np.testing.assert_array_equal(got, want)


@settings(max_examples=100, deadline=None)
@given(st.floats(-2.0, 2.0), st.floats(0.1, 0.95), st.floats(1e-3, 1e3))
def test_the_barrier_is_zero_above_its_ratio_continuous_and_its_push_is_minus_its_slope(J, j_b, kappa):
    e, push = volume_barrier(J, kappa, j_b)
    if J >= j_b:
        assert e == 0.0 and push == 0.0
        return
    assert e > 0.0 and push > 0.0  # it costs and pushes outwards
    h = 1e-6
    slope = (volume_barrier(J + h, kappa, j_b)[0] - volume_barrier(J - h, kappa, j_b)[0]) / (2 * h)
    assert -slope == pytest.approx(push, rel=1e-4)
    # continuous with zero slope where it starts, so the energy stays smooth
    assert volume_barrier(j_b - 1e-9, kappa, j_b)[0] < 1e-12 * kappa + 1e-15


@st.composite
def far_fields(draw):
    """Nodes with coarse ids and weights (some rows all zero: nodes the field leaves alone), a coarse
    field Y, positions, anchors, the last field and which nodes sleep."""
    n, nc = draw(st.integers(1, 30)), draw(st.integers(1, 10))
    cids = draw(arrays(np.int64, (n, 8), elements=st.integers(0, nc - 1)))
    cw = draw(arrays(np.float64, (n, 8), elements=st.floats(0, 1, allow_nan=False)))
    cw[draw(arrays(np.bool_, n))] = 0.0
    Y = draw(arrays(np.float64, (nc, 3), elements=finite))
    rest, x, anchor, far_u = (draw(arrays(np.float64, (n, 3), elements=finite)) for _ in range(4))
    return cids, cw, Y, rest, x, anchor, far_u, draw(arrays(np.bool_, n))


@settings(max_examples=60, deadline=None)
@given(far_fields())
def test_follow_far_places_sleepers_on_the_interpolated_field_as_a_plain_loop_does(case):
    cids, cw, Y, rest, x, anchor, far_u, sleeping = case
    u = np.einsum("nk,nka->na", cw, Y[cids])  # the plain reference: the trilinear sum per node
    want_x = np.where(sleeping[:, None], rest + u, x)
    want_anchor = anchor + u - far_u
    got_x, got_anchor, got_u, moved = x.copy(), anchor.copy(), far_u.copy(), np.full_like(x, np.nan)
    top = follow_far(cids, cw, Y, rest, got_x, got_anchor, got_u, sleeping, moved)
    np.testing.assert_allclose(got_u, u, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got_x, want_x, rtol=1e-12, atol=1e-11)
    np.testing.assert_allclose(got_anchor, want_anchor, rtol=1e-12, atol=1e-11)
    np.testing.assert_allclose(moved, want_x - x, rtol=1e-12, atol=1e-11)
    assert top == pytest.approx(float(np.abs(want_x - x).max(initial=0.0)), rel=1e-12, abs=1e-11)

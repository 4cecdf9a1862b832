"""Gibson's grid ChainMail (thesis 4.2) and its relative-limit form (4.3)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.kernels.chainmail import cascade, material_arrays
from chainsim.systems.engine.kernels.gibson import gibson_grid_move, relative_grid_move
from chainsim.systems.engine.kernels.graph import build_graph

SHAPES = [(7, 5), (4, 6), (4, 3, 5), (5, 4, 3)]


def axis_of_link(rest, links):
    return np.argmax(np.abs(rest[links[:, 1]] - rest[links[:, 0]]), axis=1)


def assert_limits(pos, rest, links, lo, hi, shear, relative, tol=1e-9):
    """Every linked pair within its compression/stretch range along the link axis and shear across."""
    ax = axis_of_link(rest, links)
    a, b = links[:, 0], links[:, 1]  # meshgen orders each pair lowest id first: b is the + neighbour
    scale = np.linalg.norm(rest[b] - rest[a], axis=1) if relative else np.ones(len(links))
    d = pos[b] - pos[a]
    along = d[np.arange(len(links)), ax]
    assert np.all(along >= np.asarray(lo)[ax] * scale - tol)
    assert np.all(along <= np.asarray(hi)[ax] * scale + tol)
    side = np.abs(d)
    side[np.arange(len(links)), ax] = 0.0
    assert np.all(side.max(axis=1) <= np.asarray(shear)[ax] * scale + tol)


@pytest.mark.parametrize("shape", SHAPES)
def test_rigid_grid_translates(shape):
    rest, links = meshgen.grid(shape, spacing=0.5)
    pos = rest.copy()
    grabbed = len(rest) // 2
    shift = np.linspace(1.3, -0.7, len(shape))
    n_moved, moved = gibson_grid_move(pos, shape, grabbed, rest[grabbed] + shift, 0.5, 0.5, 0.0, return_moved=True)
    assert n_moved == len(rest) and sorted(moved.tolist()) == list(range(len(rest)))
    np.testing.assert_allclose(pos, rest + shift, atol=1e-12)


@pytest.mark.parametrize("shape", SHAPES)
def test_rigid_grid_equals_generalised_chainmail(shape):
    rest, links = meshgen.grid(shape, spacing=1.0)
    grabbed = 1 + shape[0]
    target = rest[grabbed] + np.linspace(2.0, -1.0, len(shape))
    pos_g = rest.copy()
    gibson_grid_move(pos_g, shape, grabbed, target, 1.0, 1.0, 0.0)
    pos_c = rest.copy()
    cascade(
        rest,
        pos_c,
        build_graph(len(rest), links),
        *material_arrays(len(links), 1, 1, 0),
        np.array([grabbed]),
        target[None],
    )
    np.testing.assert_array_equal(pos_g, pos_c)


@settings(max_examples=40, deadline=None)
@given(
    st.sampled_from(SHAPES), st.integers(0, 2**32 - 1), st.floats(0.3, 1.0), st.floats(1.0, 2.5), st.floats(0.0, 0.8)
)
def test_absolute_limits_hold_on_every_link(shape, seed, lo, hi, shear):
    rng = np.random.default_rng(seed)
    rest, links = meshgen.grid(shape, spacing=1.0)
    pos = rest.copy()
    dim = len(shape)
    for _ in range(3):  # successive drags from the deformed state
        grabbed = int(rng.integers(len(rest)))
        target = pos[grabbed] + rng.normal(scale=2.0, size=dim)
        n_moved = gibson_grid_move(pos, shape, grabbed, target, lo, hi, shear)
        assert 1 <= n_moved <= len(rest)
        np.testing.assert_array_equal(pos[grabbed], target)
        assert_limits(pos, rest, links, [lo] * dim, [hi] * dim, [shear] * dim, relative=False)


@settings(max_examples=40, deadline=None)
@given(
    st.sampled_from(SHAPES), st.integers(0, 2**32 - 1), st.floats(0.3, 1.0), st.floats(1.0, 2.5), st.floats(0.0, 0.8)
)
def test_relative_limits_hold_on_a_non_uniform_grid(shape, seed, lo, hi, shear):
    rng = np.random.default_rng(seed)
    spacing = [np.cumsum(rng.uniform(0.2, 3.0, n)) for n in shape]
    rest, links = meshgen.grid(shape, spacing=spacing)
    pos = rest.copy()
    dim = len(shape)
    grabbed = int(rng.integers(len(rest)))
    target = pos[grabbed] + rng.normal(scale=3.0, size=dim)
    relative_grid_move(pos, rest, shape, grabbed, target, lo, hi, shear)
    np.testing.assert_array_equal(pos[grabbed], target)
    assert_limits(pos, rest, links, [lo] * dim, [hi] * dim, [shear] * dim, relative=True)


def test_relative_rigid_non_uniform_grid_translates():
    shape = (5, 4, 3)
    spacing = [np.array([0.0, 0.1, 0.5, 2.0, 2.2]), np.array([0.0, 1.0, 1.5, 4.0]), np.array([0.0, 0.3, 3.0])]
    rest, links = meshgen.grid(shape, spacing=spacing)
    pos = rest.copy()
    shift = np.array([0.4, -2.0, 1.0])
    n = relative_grid_move(pos, rest, shape, 17, rest[17] + shift, 1.0, 1.0, 0.0)
    assert n == len(rest)
    np.testing.assert_allclose(pos, rest + shift, atol=1e-12)


def test_soft_material_moves_only_part_of_the_grid_and_fixed_stay():
    shape = (9, 9)
    rest, links = meshgen.grid(shape)
    pos = rest.copy()
    fixed = np.zeros(len(rest), bool)
    fixed[:9] = True  # bottom row anchored
    n, moved = gibson_grid_move(pos, shape, 40, rest[40] + [0.3, 0.2], 0.7, 1.3, 0.2, fixed=fixed, return_moved=True)
    assert 1 < n < len(rest)
    untouched = np.setdiff1d(np.arange(len(rest)), moved)
    np.testing.assert_array_equal(pos[untouched], rest[untouched])
    np.testing.assert_array_equal(pos[fixed], rest[fixed])


def test_bad_grid_arguments_raise():
    rest, _ = meshgen.grid((3, 3))
    with pytest.raises(ValueError, match="pos"):
        gibson_grid_move(rest.copy(), (3, 4), 0, [0, 0], 1, 1, 0)
    with pytest.raises(ValueError, match="grabbed"):
        gibson_grid_move(rest.copy(), (3, 3), 9, [0, 0], 1, 1, 0)
    with pytest.raises(ValueError, match="min_dx"):
        gibson_grid_move(rest.copy(), (3, 3), 0, [0, 0], 2, 1, 0)
    with pytest.raises(ValueError, match="min_rel"):
        relative_grid_move(rest.copy(), rest, (3, 3), 0, [0, 0], -1, 1, 0)

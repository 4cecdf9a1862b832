"""Transform.apply / inverse_apply, the one local <-> world conversion of points, against a rotation
matrix built from the axis and angle by Rodrigues' formula (not from the quaternion code)."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.components.core import Transform, to_world

finite = st.floats(-1e3, 1e3, allow_nan=False)
vec3 = st.tuples(finite, finite, finite)
axis = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(lambda a: sum(c * c for c in a) > 1e-4)
angle = st.floats(-2 * math.pi, 2 * math.pi)
scale = st.floats(1e-3, 1e3)
points = st.lists(vec3, min_size=1, max_size=8)


def rodrigues(axis, angle) -> np.ndarray:
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * (kx @ kx)


def transform(axis, angle, position, s) -> Transform:
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    q = np.array([math.cos(angle / 2), *(k * math.sin(angle / 2))])
    return Transform(np.asarray(position, float), q, s)


@settings(max_examples=200, deadline=None)
@given(axis, angle, vec3, scale, points)
def test_apply_scales_rotates_then_moves_like_a_rotation_matrix(ax, ang, position, s, pts):
    tr = transform(ax, ang, position, s)
    local = np.asarray(pts, float)
    expected = (rodrigues(ax, ang) @ (s * local).T).T + np.asarray(position)
    got = tr.apply(local)
    assert got.shape == local.shape and got.dtype == np.float64
    tol = 1e-9 * (1 + s * np.abs(local).max() + np.abs(position).max())
    np.testing.assert_allclose(got, expected, rtol=0, atol=tol)
    # one point, shape (3,), the same as a row of the array
    np.testing.assert_allclose(tr.apply(local[0]), got[0], rtol=0, atol=tol)


@settings(max_examples=200, deadline=None)
@given(axis, angle, vec3, scale, points)
def test_inverse_apply_undoes_apply(ax, ang, position, s, pts):
    tr = transform(ax, ang, position, s)
    world = np.asarray(pts, float)
    local = tr.inverse_apply(world)
    expected = (rodrigues(ax, ang).T @ (world - np.asarray(position)).T).T / s
    tol = 1e-9 * (1 + (np.abs(world).max() + np.abs(position).max()) / s)
    np.testing.assert_allclose(local, expected, rtol=0, atol=tol)
    np.testing.assert_allclose(tr.apply(local), world, rtol=0, atol=1e-9 * (1 + np.abs(world).max()))


def test_an_entity_without_a_transform_sits_at_the_origin():
    pts = np.array([[1.5, -2.0, 3.25]], dtype=np.float32)
    out = to_world(None, pts)
    assert out.dtype == np.float64
    np.testing.assert_array_equal(out, pts)
    tr = Transform(np.array([1.0, 2.0, 3.0]), np.array([0.0, 0.0, 0.0, 1.0]), 2.0)  # half a turn about z
    np.testing.assert_allclose(to_world(tr, pts), [[1.0 - 3.0, 2.0 + 4.0, 3.0 + 6.5]], atol=1e-12)

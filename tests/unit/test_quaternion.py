"""Quaternion algebra of thesis 3.3.5 (eq. 3.1, the product formula) against rotation matrices."""

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.systems.engine import quaternion as Q

finite = st.floats(-1.0, 1.0, allow_nan=False)
vec3 = st.tuples(finite, finite, finite).filter(lambda v: np.linalg.norm(v) > 1e-3)
angle = st.floats(-2 * math.pi, 2 * math.pi, allow_nan=False)


def rodrigues(axis, a):
    u = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -u[2], u[1]], [u[2], 0, -u[0]], [-u[1], u[0], 0]])
    return np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * k @ k


def test_axis_angle_is_eq_3_1():
    q = Q.from_axis_angle([0, 0, 2.0], math.pi / 3)
    assert np.allclose(q, [math.cos(math.pi / 6), 0, 0, math.sin(math.pi / 6)])


def test_product_formula_matches_hamilton_units():
    i, j, k = np.eye(4)[1], np.eye(4)[2], np.eye(4)[3]
    assert np.allclose(Q.mul(i, j), k)
    assert np.allclose(Q.mul(j, i), -k)
    assert np.allclose(Q.mul(i, i), [-1, 0, 0, 0])


@settings(max_examples=50, deadline=None)
@given(vec3, angle, vec3)
def test_rotate_matches_rodrigues(axis, a, v):
    q = Q.from_axis_angle(axis, a)
    assert np.allclose(Q.rotate(q, v), rodrigues(axis, a) @ np.asarray(v), atol=1e-12)
    assert np.allclose(Q.to_matrix(q), rodrigues(axis, a), atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(vec3, angle, vec3, angle, vec3)
def test_concatenation_is_matrix_product(a1, t1, a2, t2, v):
    q1, q2 = Q.from_axis_angle(a1, t1), Q.from_axis_angle(a2, t2)
    both = Q.concat(q1, q2)  # q1 first
    expect = rodrigues(a2, t2) @ rodrigues(a1, t1) @ np.asarray(v)
    assert np.allclose(Q.rotate(both, v), expect, atol=1e-12)
    assert np.allclose(Q.rotate(Q.mul(Q.conjugate(both), both), v), v, atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(vec3, angle)
def test_matrix_round_trip(axis, a):
    q = Q.from_axis_angle(axis, a)
    q2 = Q.from_matrix(Q.to_matrix(q))
    assert np.allclose(Q.to_matrix(q2), Q.to_matrix(q), atol=1e-12)


def test_look_rotation_points_local_z_forward_and_y_up():
    f = np.array([-0.3, -0.8, 0.5])
    q = Q.look_rotation(f)
    assert np.allclose(Q.rotate(q, [0, 0, 1]), f / np.linalg.norm(f))
    y = Q.rotate(q, [0, 1, 0])
    assert y[2] > 0 and abs(y @ f) < 1e-12


def test_a_million_incremental_rotations_stay_unit_and_accurate():
    step = Q.from_axis_angle([0.3, -0.5, 0.8], 2 * math.pi / 1000.0)
    q = Q.IDENTITY.copy()
    for _ in range(1_000_000):
        q = Q.normalize(Q.mul(step, q))
    assert abs(Q.norm(q) - 1.0) < 1e-12
    # 1000 full turns: back where we started, to accumulated round-off
    assert np.allclose(Q.to_matrix(q), np.eye(3), atol=1e-6)

"""The projective body's forces are the gradient of the energy its module states, the corotational
W = sum_tets mu V |F - R|^2 + lambda V / 2 (tr(R^T F) - 3)^2 with R the polar rotation of F.

The reference here is written from that formula alone (numpy SVD for R, P1 shape functions from the
rest corners), and is what the other projective tests minimise with scipy as an independent FEM:
forces against its finite-difference gradient on random deformations, the forces' finite-difference
Jacobian symmetric, and the patch test (a uniform deformation: no force inside, the analytic traction
on the boundary).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.optimize as so
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from chainsim.systems.engine.bodies.projective import ProjectiveBody
from chainsim.systems.engine.meshgen import tet_grid


def lame(E, nu):
    return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))


def _rest(rest, tets):
    p = rest[tets]
    dm = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)
    return np.linalg.inv(dm), np.abs(np.linalg.det(dm)) / 6.0


def _kinematics(x, rest, tets):
    dm_inv, vol = _rest(rest, tets)
    p = x[tets]
    ds = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)
    F = ds @ dm_inv
    U, _, Vt = np.linalg.svd(F)
    fix = np.ones((len(F), 3))
    fix[:, 2] = np.linalg.det(U @ Vt)  # the nearest proper rotation, also for a reflection
    R = (U * fix[:, None, :]) @ Vt
    return F, R, dm_inv, vol


def energy(x, rest, tets, mu, lam):
    """The stated energy (joules) at positions x (N, 3), both in metres."""
    F, R, _, vol = _kinematics(x, rest, tets)
    tr = np.einsum("tij,tij->t", R, F)
    return float(np.sum(vol * (mu * np.sum((F - R) ** 2, axis=(1, 2)) + 0.5 * lam * (tr - 3.0) ** 2)))


def gradient(x, rest, tets, mu, lam):
    """dW/dx (N, 3): P = 2 mu (F - R) + lambda (tr(R^T F) - 3) R, H = V P Dm^-T onto the corners."""
    F, R, dm_inv, vol = _kinematics(x, rest, tets)
    tr = np.einsum("tij,tij->t", R, F)
    P = 2 * mu * (F - R) + (lam * (tr - 3.0))[:, None, None] * R
    H = vol[:, None, None] * P @ np.transpose(dm_inv, (0, 2, 1))
    g = np.zeros_like(x)
    for k in range(3):
        np.add.at(g, tets[:, k + 1], H[:, :, k])
        np.add.at(g, tets[:, 0], -H[:, :, k])
    return g


def minimise(rest, tets, mu, lam, held, x_held, x0=None):
    """The static equilibrium of the stated energy with nodes `held` at `x_held`: scipy's trust-region
    Newton on the free coordinates, the Hessian by central differences of `gradient`."""
    free = np.setdiff1d(np.arange(len(rest)), held)
    x = (rest if x0 is None else x0).copy()
    x[held] = x_held

    def full(z):
        y = x.copy()
        y[free] = z.reshape(-1, 3)
        return y

    scale = mu * np.ptp(rest, axis=0).max()

    def fun(z):
        return energy(full(z), rest, tets, mu, lam) / scale

    def jac(z):
        return gradient(full(z), rest, tets, mu, lam)[free].ravel() / scale

    def hess(z):
        h = 1e-7 * np.ptp(rest, axis=0).max()
        cols = []
        for j in range(len(z)):
            e = np.zeros_like(z)
            e[j] = h
            cols.append((jac(z + e) - jac(z - e)) / (2 * h))
        H = np.array(cols)
        return 0.5 * (H + H.T)

    z0 = x[free].ravel()
    res = so.minimize(fun, z0, jac=jac, hess=hess, method="trust-exact", options={"gtol": 1e-11, "maxiter": 200})
    g = np.abs(jac(res.x)).max()
    assert g < 1e-8, f"reference minimisation did not converge ({res.message}, gradient {g:g})"
    return full(res.x)


def _rotation(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_the_reference_gradient_is_its_energys():
    pos, tets, _ = tet_grid(2, 2, 2, spacing=1.0)
    x = pos + np.random.default_rng(0).normal(size=pos.shape) * 0.1
    g = gradient(x, pos, tets, 2.0, 7.0)
    h = 1e-6
    for i, c in [(0, 0), (3, 1), (7, 2)]:
        y = x.copy()
        y[i, c] += h
        e1 = energy(y, pos, tets, 2.0, 7.0)
        y[i, c] -= 2 * h
        assert g[i, c] == pytest.approx((e1 - energy(y, pos, tets, 2.0, 7.0)) / (2 * h), rel=1e-6, abs=1e-9)


def test_the_reference_energy_of_a_uniaxial_stretch_is_the_formulas():
    pos, tets, _ = tet_grid(2, 2, 2, spacing=1.0)
    mu, lam, s = 2.0, 7.0, 1.1
    assert energy(pos * [s, 1, 1], pos, tets, mu, lam) == pytest.approx(mu * 0.01 + 0.5 * lam * 0.01, rel=1e-12)


@settings(max_examples=25, deadline=None)
@given(
    noise=arrays(np.float64, (27, 3), elements=st.floats(-0.15, 0.15)),
    axis=arrays(np.float64, 3, elements=st.floats(-1, 1)).filter(lambda v: np.linalg.norm(v) > 0.1),
    angle=st.floats(-1.5, 1.5),
    stretch=arrays(np.float64, (3, 3), elements=st.floats(-0.3, 0.3)),
    E=st.floats(1e2, 1e6),
    nu=st.floats(0.0, 0.499),
    unit=st.sampled_from([1.0, 1e-3]),
)
def test_forces_are_minus_the_energy_gradient(noise, axis, angle, stretch, E, nu, unit):
    pos, tets, _ = tet_grid(3, 3, 3, spacing=1.0)
    A = _rotation(axis, angle) @ (np.eye(3) + 0.5 * (stretch + stretch.T))
    y = pos @ A.T + noise
    F, *_ = _kinematics(y, pos, tets)
    assume(np.linalg.det(F).min() > 0.2)  # no element near inversion, where R is not smooth
    body = ProjectiveBody(pos, tets, E=E, nu=nu, unit=unit)
    body.positions = y
    got = body.elastic_forces()
    mu, lam = lame(E, nu)
    x, rest = y * unit, pos * unit
    h = 1e-6 * unit
    want = np.zeros_like(x)
    for i in range(len(x)):
        for c in range(3):
            z = x.copy()
            z[i, c] += h
            e1 = energy(z, rest, tets, mu, lam)
            z[i, c] -= 2 * h
            want[i, c] = -(e1 - energy(z, rest, tets, mu, lam)) / (2 * h)
    # relative to the forces, or to those of a 1e-6 strain where the deformation is (nearly) rigid
    assert np.linalg.norm(got - want) <= 1e-5 * max(np.linalg.norm(want), 1e-6 * E * unit**2)


@settings(max_examples=6, deadline=None)
@given(
    noise=arrays(np.float64, (27, 3), elements=st.floats(-0.2, 0.2)),
    nu=st.sampled_from([0.3, 0.45, 0.499]),
)
def test_the_stiffness_is_symmetric(noise, nu):
    pos, tets, _ = tet_grid(3, 3, 3, spacing=1.0)
    y = pos * [1.1, 0.95, 1.0] + noise
    F, *_ = _kinematics(y, pos, tets)
    assume(np.linalg.det(F).min() > 0.2)
    body = ProjectiveBody(pos, tets, E=1e4, nu=nu)
    h = 1e-5
    J = np.zeros((y.size, y.size))
    for j in range(y.size):
        z = y.copy().ravel()
        z[j] += h
        body.positions = z.reshape(-1, 3)
        fp = body.elastic_forces().ravel()
        z[j] -= 2 * h
        body.positions = z.reshape(-1, 3)
        J[:, j] = (fp - body.elastic_forces().ravel()) / (2 * h)
    assert np.linalg.norm(J - J.T) <= 1e-6 * np.linalg.norm(J)


def _boundary_triangles(rest, tets):
    """Faces used by one tetrahedron only, with their outward normals times area."""
    faces = {}
    for t in tets:
        for k in range(4):
            f = tuple(np.delete(t, k))
            key = tuple(sorted(f))
            faces.setdefault(key, []).append((f, t[k]))
    out = []
    for users in faces.values():
        if len(users) != 1:
            continue
        (a, b, c), opp = users[0]
        n = 0.5 * np.cross(rest[b] - rest[a], rest[c] - rest[a])
        if np.dot(n, rest[opp] - rest[a]) > 0:
            n = -n
        out.append(((a, b, c), n))
    return out


@pytest.mark.parametrize("unit", [1.0, 1e-3])
@pytest.mark.parametrize("stretches", [(1.1, 1.0, 1.0), (0.9, 1.2, 1.05)])
def test_patch_test_uniform_deformation(unit, stretches):
    pos, tets, _ = tet_grid(4, 4, 4, spacing=1.0)
    E, nu = 3000.0, 0.45
    Q = _rotation([1, 2, 3], 0.7)
    F = Q @ np.diag(stretches)
    body = ProjectiveBody(pos, tets, E=E, nu=nu, unit=unit)
    body.positions = pos @ F.T + [0.3, -0.2, 5.0]
    got = body.elastic_forces()
    mu, lam = lame(E, nu)
    P = 2 * mu * (F - Q) + lam * (sum(stretches) - 3.0) * Q  # first Piola stress of the stated energy
    rest = pos * unit
    want = np.zeros_like(rest)
    for tri, n in _boundary_triangles(rest, tets):
        for i in tri:
            want[i] -= P @ n / 3.0  # the traction P N on a P1 face, a third to each corner
    interior = np.all((pos > 0.5) & (pos < 2.5), axis=1)
    assert interior.sum() == 8
    big = np.abs(want).max()
    np.testing.assert_allclose(got[interior], 0.0, atol=1e-10 * big)
    np.testing.assert_allclose(got, want, atol=1e-9 * big)

"""XPBD at surgical scale: millimetre meshes, 1-100 kPa, nu up to 0.499, 60 Hz frames.

The references are written here, independently of the kernels: tetrahedron volumes from the corner
positions, the corotational energy with the rotation from numpy's SVD (the kernel uses quaternions),
its minimum by scipy's L-BFGS, and the affine field of a uniform stretch (the patch test).
"""

from __future__ import annotations

import logging
import re
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy.optimize import minimize

from chainsim.systems.engine.bodies import xpbd
from chainsim.systems.engine.bodies.xpbd import XPBDBody, tet_rest_data
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels.xpbd import corot_forces, corot_sweep
from chainsim.systems.engine.meshgen import tet_grid

FRAME = 1.0 / 60.0


def _cube(n: int, size_mm: float):
    pos, tets, _ = tet_grid(n, n, n, spacing=size_mm / (n - 1))
    return pos, tets, np.flatnonzero(pos[:, 2] < 1e-9)


def _signed_volumes(x, tets):
    p = x[tets]
    return np.einsum("ij,ij->i", np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), p[:, 3] - p[:, 0]) / 6.0


def _lame(E, nu):
    return E / (2 * (1 + nu)), E * nu / ((1 + nu) * (1 - 2 * nu))


def _np_energy_and_grad(x, tets, dm_inv, vol, mu, lam):
    """Corotational energy sum V (mu |F - R|^2 + lam/2 (J - 1)^2) and its gradient, R from the SVD."""
    ds = np.stack([x[tets[:, i]] - x[tets[:, 0]] for i in (1, 2, 3)], axis=2)
    F = ds @ dm_inv
    U, _, Vt = np.linalg.svd(F)
    d = np.linalg.det(U @ Vt)
    U[:, :, 2] *= d[:, None]
    R = U @ Vt
    J = np.linalg.det(F)
    cof = np.linalg.inv(F).transpose(0, 2, 1) * J[:, None, None]
    e = np.sum(vol * (mu * np.sum((F - R) ** 2, axis=(1, 2)) + 0.5 * lam * (J - 1) ** 2))
    H = vol[:, None, None] * (2 * mu * (F - R) + lam * (J - 1)[:, None, None] * cof) @ dm_inv.transpose(0, 2, 1)
    g = np.zeros_like(x)
    for k in range(3):
        np.add.at(g, tets[:, k + 1], H[:, :, k])
        np.add.at(g, tets[:, 0], -H[:, :, k])
    return e, g


def _static_reference(pos, tets, held, targets, E, nu, unit=1e-3):
    """The minimum of the corotational energy with `held` nodes at `targets` (mm), by L-BFGS."""
    mu, lam = _lame(E, nu)
    rest = pos * unit
    dm_inv, vol = tet_rest_data(rest, tets)
    x0 = rest.copy()
    x0[held] = targets * unit
    free = np.setdiff1d(np.arange(len(pos)), held)

    def fun(z):
        x = x0.copy()
        x[free] = z.reshape(-1, 3)
        e, g = _np_energy_and_grad(x, tets, dm_inv, vol, mu, lam)
        return e, g[free].ravel()

    r = minimize(fun, x0[free].ravel(), jac=True, method="L-BFGS-B", options={"maxiter": 20000, "ftol": 1e-16})
    x = x0.copy()
    x[free] = r.x.reshape(-1, 3)
    return x / unit


# -- at rest --------------------------------------------------------------------------------------


@pytest.mark.parametrize("n,size", [(7, 30.0), (5, 4.0)])  # 5 mm and 1 mm tetrahedra
@pytest.mark.parametrize("E", [1e3, 3e4, 1e5])
@pytest.mark.parametrize("nu", [0.45, 0.499])
def test_a_body_left_alone_stays_at_rest(n, size, E, nu):
    pos, tets, fixed = _cube(n, size)
    b = XPBDBody(pos, tets, E=E, nu=nu, unit=1e-3, fixed=fixed)
    for _ in range(30):
        b.step(FRAME)
    assert np.max(np.abs(b.positions - pos)) <= 1e-9 * size
    assert b.substeps == b.substeps_needed(FRAME)


# -- under a pull ---------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize(
    "n,size,E,nu,pull",
    [
        (7, 30.0, 1e5, 0.499, (0.0, 0.0, 12.0)),  # skin, 40 % stretch
        (7, 30.0, 3e4, 0.45, (12.0, 0.0, 0.0)),  # shear
        (7, 30.0, 1e3, 0.45, (0.0, 0.0, -9.0)),  # fat pushed in 30 %
        (9, 8.0, 1e4, 0.45, (0.0, 0.0, -2.5)),  # 1 mm tetrahedra pushed in
    ],
)
def test_a_pull_inverts_no_tetrahedron(n, size, E, nu, pull):
    pos, tets, fixed = _cube(n, size)
    c = size / 2
    top = np.flatnonzero(
        (pos[:, 2] > size - 1e-9)
        & (np.abs(pos[:, 0] - c) <= size / 4 + 1e-9)
        & (np.abs(pos[:, 1] - c) <= size / 4 + 1e-9)
    )
    b = XPBDBody(pos, tets, E=E, nu=nu, unit=1e-3, fixed=fixed)
    sign = np.sign(_signed_volumes(pos, tets))
    for f in range(60):
        b.grab(top, pos[top] + min(1.0, (f + 1) / 30) * np.asarray(pull))
        b.step(FRAME)
        assert np.all(np.isfinite(b.positions))
        assert np.all(sign * _signed_volumes(b.positions, tets) > 0.0), f"a tetrahedron inverted in frame {f}"


class _Said(logging.Handler):
    """The lines a logger says (on the logger itself: the command line's set-up stops propagation)."""

    def __init__(self):
        super().__init__(logging.WARNING)
        self.lines: list[str] = []

    def emit(self, record):
        self.lines.append(record.getMessage())


def test_fewer_substeps_than_the_rule_are_honoured_with_a_warning():
    pos, tets, fixed = _cube(5, 4.0)
    b = XPBDBody(pos, tets, E=3e4, nu=0.45, unit=1e-3, fixed=fixed, substeps=4)
    said, log = _Said(), logging.getLogger(xpbd.__name__)
    log.addHandler(said)
    try:
        b.step(FRAME)
        b.step(FRAME)  # said once per step length, not every frame
    finally:
        log.removeHandler(said)
    said = said.lines
    assert len(said) == 1 and re.search("need [0-9]+ substeps", said[0]) and "\n" not in said[0]
    assert b.substeps == 4 and "substeps" in b.notice


def test_a_step_the_rule_cannot_resolve_is_refused_in_one_line():
    pos, tets, fixed = _cube(5, 0.4)  # 0.1 mm tetrahedra of a 10 MPa material
    b = XPBDBody(pos, tets, E=1e7, nu=0.45, unit=1e-3, fixed=fixed)
    with pytest.raises(UserError, match=r"need \d+ substeps.*more than the 1000 allowed"):
        b.step(FRAME)


@pytest.mark.parametrize("bad", [0, -3, 1001, 2.5, "many", True])
def test_bad_substeps_are_refused(bad):
    pos, tets, fixed = _cube(3, 4.0)
    with pytest.raises(UserError, match="substeps"):
        XPBDBody(pos, tets, unit=1e-3, substeps=bad)


# -- convergence to the energy's minimum ----------------------------------------------------------


def _cantilever():
    pos, tets, _ = tet_grid(9, 3, 3, spacing=5.0)  # 40 x 10 x 10 mm
    fixed = np.flatnonzero(pos[:, 0] < 1e-9)
    tip = np.flatnonzero(pos[:, 0] > 40.0 - 1e-9)
    return pos, tets, fixed, tip


def _settled(b, frames):
    for _ in range(frames):
        b.step(FRAME)
    return b.positions


@pytest.mark.parametrize("E,nu", [(3e3, 0.3), (3e4, 0.45)])
def test_the_cantilever_converges_to_the_fem_minimum_of_its_energy(E, nu):
    """Settled under the substep rule, XPBD is within 5 % of the P1 minimum; more substeps come closer."""
    pos, tets, fixed, tip = _cantilever()
    pull = np.array([0.0, 0.0, -4.0])
    held = np.concatenate([fixed, tip])
    ref = _static_reference(pos, tets, held, np.concatenate([pos[fixed], pos[tip] + pull]), E, nu)
    errors = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # 2 substeps is under the rule on purpose
        for substeps in (2, "auto"):
            b = XPBDBody(pos, tets, E=E, nu=nu, unit=1e-3, fixed=fixed, substeps=substeps)
            b.grab(tip, pos[tip] + pull)
            x = _settled(b, 200)
            errors.append(np.sqrt(np.mean(np.sum((x - ref) ** 2, axis=1))) / 4.0)
    assert errors[1] < 0.05, errors
    assert errors[1] < errors[0], errors


def test_the_patch_test_converges_with_substeps():
    """A uniform stretch of the boundary: the interior settles towards the same affine field, its error
    falling as the substep squared (XPBD's steady state is the energy's minimum only in the limit)."""
    pos, tets, _ = tet_grid(4, 4, 4, spacing=5.0)
    boundary = np.flatnonzero(np.any((pos < 1e-9) | (pos > 15.0 - 1e-9), axis=1))
    A = np.array([[1.08, 0.02, 0.0], [0.0, 0.97, 0.03], [0.01, 0.0, 1.05]])
    errors = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        for substeps in (25, 100, 400):
            b = XPBDBody(pos, tets, E=1e4, nu=0.45, unit=1e-3, substeps=substeps)
            b.grab(boundary, pos[boundary] @ A.T)
            x = _settled(b, 120)
            errors.append(np.max(np.abs(x - pos @ A.T)) / 1.2)  # of the largest boundary displacement
    assert errors[0] > 8 * errors[1] > 64 * errors[2], errors
    assert errors[2] < 2e-4, errors


# -- the kernels against plain references ----------------------------------------------------------


def _one_tet():
    return np.array([[0.0, 0, 0], [1e-3, 0, 0], [0, 1e-3, 0], [0, 0, 1e-3]]), np.array([[0, 1, 2, 3]])


@settings(max_examples=40, deadline=None)
@given(
    noise=arrays(np.float64, (4, 3), elements=st.floats(-3e-4, 3e-4)),
    E=st.floats(1e2, 1e6),
    nu=st.floats(0.0, 0.49),
)
def test_corotational_forces_are_the_energy_gradient(noise, E, nu):
    rest, tets = _one_tet()
    x = rest + noise
    dm_inv, vol = tet_rest_data(rest, tets)
    mu, lam = _lame(E, nu)
    if np.linalg.det(np.stack([x[i] - x[0] for i in (1, 2, 3)], axis=1)) <= 1e-12:
        return  # the SVD reference's rotation is not the kernel's for an inverted or flat element
    got = np.zeros_like(x)
    q = np.tile([1.0, 0.0, 0.0, 0.0], (1, 1))
    corot_forces(x, tets, dm_inv, vol, np.ones(1, bool), mu, lam, q, got)
    _, g = _np_energy_and_grad(x, tets, dm_inv, vol, mu, lam)
    np.testing.assert_allclose(got, -g, atol=1e-9 * max(1.0, np.abs(g).max()), rtol=1e-6)


def _ref_corot_step(x, w, dm_inv, vol, mu, lam, h2):
    """One tet's deviatoric then volume update, written from the XPBD formula with numpy."""
    x = x.copy()

    def grads(P):
        G = P @ dm_inv[0].T
        return np.vstack([-G.sum(axis=1), G.T])

    def F_of(x):
        return np.stack([x[i] - x[0] for i in (1, 2, 3)], axis=1) @ dm_inv[0]

    F = F_of(x)
    U, _, Vt = np.linalg.svd(F)
    if np.linalg.det(U @ Vt) < 0:
        U[:, 2] *= -1
    D = F - U @ Vt
    C = np.linalg.norm(D)
    if C > 1e-14:
        g = grads(D / C)
        alpha = 1.0 / (2 * mu * vol[0] * h2)
        dl = -C / (np.sum(w[:, None] * g * g) + alpha)
        x += w[:, None] * dl * g
    F = F_of(x)
    J = np.linalg.det(F)
    g = grads(np.linalg.inv(F).T * J)
    alpha = 1.0 / (lam * vol[0] * h2)
    dl = -(J - 1.0) / (np.sum(w[:, None] * g * g) + alpha)
    return x + w[:, None] * dl * g


@settings(max_examples=40, deadline=None)
@given(
    noise=arrays(np.float64, (4, 3), elements=st.floats(-2e-4, 2e-4)),
    w=arrays(np.float64, 4, elements=st.sampled_from([0.0, 0.5, 1.0, 2.0])),
    E=st.floats(1e2, 1e6),
    nu=st.floats(0.05, 0.49),
    h=st.floats(1e-5, 1e-2),
)
def test_corot_sweep_matches_a_plain_reference(noise, w, E, nu, h):
    rest, tets = _one_tet()
    x = rest + noise
    if np.linalg.det(np.stack([x[i] - x[0] for i in (1, 2, 3)], axis=1)) <= 1e-12 or w.sum() == 0:
        return
    dm_inv, vol = tet_rest_data(rest, tets)
    mu, lam = _lame(E, nu)
    got = x.copy()
    q = np.tile([1.0, 0.0, 0.0, 0.0], (1, 1))
    z = np.zeros(1)
    corot_sweep(got, w, tets, dm_inv, vol, np.ones(1, bool), mu, lam, h * h, q, 60, z.copy(), z.copy())
    want = _ref_corot_step(x, w, dm_inv, vol, mu, lam, h * h)
    np.testing.assert_allclose(got, want, atol=1e-12)

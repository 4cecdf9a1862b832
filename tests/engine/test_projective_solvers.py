"""The projective body's global-step solvers: the CSR kernels against scipy, conjugate gradients
against a direct solve, and the CG body reaching the direct body's state; settings refused."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.systems.engine.bodies.projective import ProjectiveBody
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels.projective import extract_rotation, pcg3, spmv3
from chainsim.tools.study import scenes as sc


def _spd(n, seed):
    rng = np.random.default_rng(seed)
    A = sp.random(n, n, density=min(1.0, 4.0 / n), random_state=seed)
    A = A @ A.T + sp.diags(rng.uniform(0.5, 2.0, n))
    return A.tocsr()


@settings(max_examples=30, deadline=None)
@given(n=st.integers(1, 60), seed=st.integers(0, 10_000))
def test_spmv3_matches_scipy(n, seed):
    A = _spd(n, seed)
    x = np.random.default_rng(seed).normal(size=(n, 3))
    out = np.zeros((n, 3))
    spmv3(A.indptr.astype(np.int64), A.indices.astype(np.int64), A.data, x, out)
    np.testing.assert_allclose(out, A @ x, rtol=1e-12, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(n=st.integers(1, 60), seed=st.integers(0, 10_000), scale=st.sampled_from([1e-6, 1.0, 1e9]))
def test_pcg3_solves_what_a_direct_solve_does(n, seed, scale):
    A = _spd(n, seed) * scale
    b = np.random.default_rng(seed + 1).normal(size=(n, 3)) * scale
    want = np.linalg.solve(A.toarray(), b)
    x = np.zeros((n, 3))
    scratch = [np.zeros((n, 3)) for _ in range(4)]
    steps = pcg3(
        A.indptr.astype(np.int64),
        A.indices.astype(np.int64),
        A.data,
        1.0 / A.diagonal(),
        b,
        x,
        10 * n + 10,
        1e-13,
        *scratch,
    )
    assert steps <= 10 * n + 10
    assert np.all(np.isfinite(x))
    np.testing.assert_allclose(x, want, rtol=1e-6, atol=1e-8 * np.abs(want).max())


def test_pcg3_from_the_answer_takes_no_step():
    A = _spd(20, 3)
    b = np.ones((20, 3))
    x = np.linalg.solve(A.toarray(), b)
    scratch = [np.zeros((20, 3)) for _ in range(4)]
    assert (
        pcg3(A.indptr.astype(np.int64), A.indices.astype(np.int64), A.data, 1 / A.diagonal(), b, x, 50, 1e-8, *scratch)
        == 0
    )


def test_rotation_extraction_small_and_large_steps_agree_with_the_polar_decomposition():
    rng = np.random.default_rng(4)
    for angle in (1e-4, 0.05, 0.09, 1.0, 3.0):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        R = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K
        A = R @ np.diag([1.1, 0.9, 1.05])
        q = np.array([1.0, 0.0, 0.0, 0.0])
        got = extract_rotation(A, q, 200)
        np.testing.assert_allclose(got, R, atol=1e-8)


def test_cg_body_reaches_the_direct_bodys_state():
    s = sc.block(6)
    bodies = [
        ProjectiveBody(s.pos, s.tets, E=3000.0, nu=0.45, iterations=1, dynamic=False, fixed=s.fixed),
        ProjectiveBody(
            s.pos,
            s.tets,
            E=3000.0,
            nu=0.45,
            iterations=1,
            dynamic=False,
            fixed=s.fixed,
            solver="cg",
            cg_iterations=10,
            rotation_iterations=1,
        ),
    ]
    for b in bodies:
        b.grab(s.grabbed, s.pos[s.grabbed] + s.grab_disp(0.1))
        for _ in range(150):
            b.step(1 / 60)
    d = 0.1 * s.length
    assert np.sqrt(np.mean(np.sum((bodies[0].positions - bodies[1].positions) ** 2, axis=1))) < 1e-3 * d


@pytest.mark.parametrize("E", [1.0, 1e9])
@pytest.mark.parametrize("nu", [0.0, 0.499])
@pytest.mark.parametrize("dt", [1e-5, 0.1])
def test_cg_body_stays_finite_at_the_extremes(E, nu, dt):
    s = sc.block(5)
    b = ProjectiveBody(s.pos, s.tets, E=E, nu=nu, fixed=s.fixed, solver="cg", cg_iterations=5, rotation_iterations=1)
    b.grab(s.grabbed, s.pos[s.grabbed] + [0.0, 0.0, 0.25])
    for _ in range(10):
        b.step(dt)
    assert np.all(np.isfinite(b.positions))
    assert np.max(np.abs(b.positions - s.pos)) < 2.0


@pytest.mark.parametrize(
    "kwargs, word",
    [({"solver": "qr"}, "solver"), ({"cg_iterations": 0}, "cg_iterations"), ({"rotation_iterations": 0}, "rotation")],
)
def test_bad_solver_settings_are_refused(kwargs, word):
    s = sc.block(5)
    with pytest.raises(UserError, match=word):
        ProjectiveBody(s.pos, s.tets, **kwargs)


def test_make_body_passes_the_solver_settings():
    from chainsim.systems.engine.bodies.factory import make_body

    s = sc.block(5)
    b = make_body("projective", s.pos, tets=s.tets, solver="cg", cg_iterations=7, rotation_iterations=2, dynamic=False)
    assert (b.solver, b.cg_iterations, b.rotation_iterations, b.dynamic) == ("cg", 7, 2, False)

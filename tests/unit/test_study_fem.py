"""Reference FEM solvers of the speed-accuracy study: exactness, agreement, convergence, extremes."""

import numpy as np
import pytest

from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.meshgen import tet_grid
from chainsim.tools.study.fem_linear import LinearFEM, LockingWarning, solve_linear
from chainsim.tools.study.fem_nonlinear import NeoHookeanFEM
from chainsim.tools.study.scenes import block, cantilever
from chainsim.tools.study.tetmesh import DegenerateElementsError


def jittered_block(n=4, seed=0):
    pos, tets, _ = tet_grid(n, n, n, 1.0 / (n - 1))
    rng = np.random.default_rng(seed)
    inner = np.all((pos > 1e-9) & (pos < 1 - 1e-9), axis=1)
    pos = pos.copy()
    pos[inner] += rng.uniform(-0.08, 0.08, size=(inner.sum(), 3))
    boundary = np.flatnonzero(~inner)
    return pos, tets, boundary, np.flatnonzero(inner)


def test_patch_test_affine_field_is_reproduced_exactly():
    pos, tets, boundary, inner = jittered_block()
    A = np.array([[0.01, 0.003, -0.002], [0.004, -0.006, 0.001], [0.0, 0.002, 0.008]])
    b = np.array([0.1, -0.2, 0.05])
    exact = pos @ A.T + b
    r = solve_linear(pos, tets, 1e4, 0.3, boundary, exact[boundary])
    assert r.status == "ok"
    np.testing.assert_allclose(r.u[inner], exact[inner], atol=1e-12)


def test_linear_and_neo_hookean_agree_within_two_percent_at_one_percent_strain():
    s = block(6)
    lin = LinearFEM(s.pos, s.tets, 3000.0, 0.45, s.constrained).solve(s.constrained_disp(0.01))
    nl = NeoHookeanFEM(s.pos, s.tets, 3000.0, 0.45, s.constrained).solve_path(s.constrained_disp(1.0), [0.01])
    assert nl.status == "converged"
    err = np.linalg.norm(lin.u - nl.u[0.01], axis=1).max() / 0.01
    assert err < 0.02


def test_neo_hookean_converges_with_block_pulled_half_its_height():
    s = block(6)
    fem = NeoHookeanFEM(s.pos, s.tets, 3000.0, 0.45, s.constrained)
    res = fem.solve_path(s.constrained_disp(1.0), [0.1, 0.25, 0.5])
    assert res.status == "converged"
    u = res.u[0.5]
    assert np.all(np.isfinite(u))
    np.testing.assert_allclose(u[s.grabbed, 2], 0.5)
    assert np.isfinite(fem.energy(u.ravel()))  # no inverted element
    r, _ = fem.residual_and_tangent(u.ravel(), want_tangent=False)
    assert np.linalg.norm(r[fem.fdofs]) < 1e-6 * np.linalg.norm(r[fem.cdofs])


def test_cantilever_tip_deflection_approaches_beam_theory():
    P, E = 1.0, 1e6
    h = 0.2
    beam = P / (3 * E * h**4 / 12) + P / (5 / 6 * (E / 2) * h * h)  # bending + shear, nu = 0
    defl = []
    for n in (5, 7):
        s = cantilever(n)
        f = np.zeros((s.n_nodes, 3))
        f[s.grabbed, 2] = -P / len(s.grabbed)
        r = solve_linear(s.pos, s.tets, E, 0.0, s.fixed, forces=f)
        defl.append(-r.u[s.grabbed, 2].mean())
    assert abs(defl[1] - beam) / beam < 0.12
    assert abs(defl[1] - beam) < abs(defl[0] - beam)  # refinement approaches it


def test_nearly_incompressible_material_stays_finite_and_warns_about_locking():
    s = block(5)
    with pytest.warns(LockingWarning, match="lock"):
        lin = LinearFEM(s.pos, s.tets, 3000.0, 0.499, s.constrained)
    r = lin.solve(s.constrained_disp(0.05))
    assert r.status == "ok" and np.all(np.isfinite(r.u)) and np.abs(r.u).max() > 0
    assert any("lock" in w for w in r.warnings)
    with pytest.warns(LockingWarning):
        nl = NeoHookeanFEM(s.pos, s.tets, 3000.0, 0.499, s.constrained).solve_path(s.constrained_disp(1.0), [0.05])
    assert nl.status == "converged" and np.all(np.isfinite(nl.u[0.05]))


def test_youngs_modulus_over_six_orders_of_magnitude():
    s = block(5)
    fields, forced = [], []
    f = np.zeros((s.n_nodes, 3))
    f[s.grabbed, 2] = 1.0
    for E in (1e2, 1e5, 1e8):
        lin = LinearFEM(s.pos, s.tets, E, 0.3, s.constrained)
        fields.append(lin.solve(s.constrained_disp(0.05)).u)
        free_load = LinearFEM(s.pos, s.tets, E, 0.3, s.fixed).solve(None, f).u
        assert np.all(np.isfinite(free_load))
        forced.append(free_load * E)
        nl = NeoHookeanFEM(s.pos, s.tets, E, 0.3, s.constrained).solve_path(s.constrained_disp(1.0), [0.05])
        fields.append(nl.u[0.05])
    # displacement-driven: the same field whatever E; force-driven: displacement scales as 1/E
    np.testing.assert_allclose(fields[2], fields[0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(fields[4], fields[0], rtol=0, atol=1e-10)
    np.testing.assert_allclose(fields[3], fields[1], rtol=0, atol=1e-7)
    np.testing.assert_allclose(forced[2], forced[0], rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(forced[1], forced[0], rtol=1e-6, atol=1e-12)


def test_near_zero_volume_tetrahedra_are_reported_by_id():
    pos, tets, _ = tet_grid(3, 3, 3, 0.5)
    pos = pos.copy()
    # flatten the tets around node 13 (the centre) by moving it onto its neighbour's plane
    bad_node = 13
    pos[bad_node] = pos[
        tets[np.any(tets == bad_node, axis=1)][0][tets[np.any(tets == bad_node, axis=1)][0] != bad_node][:3]
    ].mean(axis=0)
    with pytest.raises(DegenerateElementsError) as exc:
        LinearFEM(pos, tets, 1e3, 0.3, [0])
    ids = exc.value.element_ids
    assert len(ids) >= 1
    assert str(int(ids[0])) in str(exc.value)
    assert isinstance(exc.value, UserError)
    x = pos[tets[ids]]
    vol = np.abs(np.linalg.det(np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], 2))) / 6
    assert np.all(vol < 1e-6 * 0.5**3)


def test_bad_material_is_a_user_error():
    s = block(3)
    for E, nu in ((-1.0, 0.3), (1.0, 0.5), (1.0, float("nan"))):
        with pytest.raises(UserError):
            LinearFEM(s.pos, s.tets, E, nu, s.constrained)

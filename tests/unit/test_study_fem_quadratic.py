"""Quadratic (P2) tetrahedra, the study's non-locking force reference: exactness on quadratic fields,
beam theory on a cantilever at nu = 0.45 where P1 locks, and the forces section built from it."""

from __future__ import annotations

import numpy as np
import pytest

from chainsim.tools.study import scenes as sc
from chainsim.tools.study.fem_linear import LinearFEM, solve_linear
from chainsim.tools.study.fem_nonlinear import NeoHookeanFEM
from chainsim.tools.study.fem_quadratic import QuadraticFEM, face_load, quadratic_mesh
from chainsim.tools.study.forces import reference_forces
from chainsim.tools.study.report import forces_section

E = 3000.0


def _timoshenko(P, nu, L=1.0, h=0.2):
    G = E / (2 * (1 + nu))
    kappa = 10 * (1 + nu) / (12 + 11 * nu)  # Cowper's shear coefficient of a rectangle
    return P * L**3 / (3 * E * h**4 / 12) + P * L / (kappa * G * h * h)


def test_midpoints_sit_on_their_edges():
    s = sc.block(5)
    pos2, tets10, edges = quadratic_mesh(s.pos, s.tets)
    assert len(pos2) == s.n_nodes + len(edges)
    np.testing.assert_allclose(pos2[tets10[:, 4]], 0.5 * (pos2[tets10[:, 0]] + pos2[tets10[:, 1]]))
    np.testing.assert_allclose(pos2[tets10[:, 9]], 0.5 * (pos2[tets10[:, 2]] + pos2[tets10[:, 3]]))


def test_quadratic_displacement_field_has_the_exact_stiffness_energy():
    """A quadratic field is in the P2 space: its energy u.K.u equals the integral of the strain energy."""
    s = sc.block(5)
    fem = QuadraticFEM(s.pos, s.tets, E, 0.3, s.fixed)
    x = fem.pos2
    eps = 1e-3
    u = np.stack([eps * x[:, 0] ** 2, np.zeros(len(x)), np.zeros(len(x))], axis=1)  # strain e_xx = 2 eps x
    lam, mu = E * 0.3 / (1.3 * 0.4), E / 2.6
    want = 0.5 * (lam + 2 * mu) * (2 * eps) ** 2 / 3.0  # int_0^1 (lam + 2mu)/2 (2 eps x)^2 dx over the unit cube
    assert 0.5 * u.ravel() @ (fem.K @ u.ravel()) == pytest.approx(want, rel=1e-9)


def test_rigid_motion_is_force_free():
    s = sc.block(5)
    fem = QuadraticFEM(s.pos, s.tets, E, 0.45, s.fixed)
    u = np.tile([0.1, -0.2, 0.3], (len(fem.pos2), 1))
    np.testing.assert_allclose(fem.K @ u.ravel(), 0.0, atol=1e-9)


@pytest.mark.parametrize("nu", [0.0, 0.45])
def test_cantilever_meets_beam_theory_where_p1_locks(nu):
    P = 1.0
    s = sc.cantilever(5)
    fem = QuadraticFEM(s.pos, s.tets, E, nu, s.fixed)
    tip = s.pos[:, 0] > 1.0 - 1e-9
    u = fem.solve(None, face_load(fem, s.tets, tip, [0.0, 0.0, -P]))
    ratio = -u[: s.n_nodes][tip, 2].mean() / _timoshenko(P, nu)
    # the clamp also stops the Poisson contraction at the wall, which beam theory ignores: a few % stiffer
    assert 0.95 < ratio < 1.01
    f1 = np.zeros((s.n_nodes, 3))
    f1[s.grabbed, 2] = -P / len(s.grabbed)
    p1 = -solve_linear(s.pos, s.tets, E, nu, s.fixed, forces=f1).u[s.grabbed, 2].mean() / _timoshenko(P, nu)
    if nu > 0.4:
        assert p1 < 0.65  # the locking the P2 reference is there to avoid


def test_reactions_balance_and_imposed_values_are_met():
    s = sc.block(5)
    fem = QuadraticFEM(s.pos, s.tets, E, 0.45, s.constrained)
    u = fem.solve(s.constrained_disp(0.1))
    np.testing.assert_allclose(u[s.grabbed], s.grab_disp(0.1))
    np.testing.assert_allclose(u[s.fixed], 0.0)
    np.testing.assert_allclose(fem.reaction(u, s.grabbed), -fem.reaction(u, s.fixed), rtol=1e-8, atol=1e-9)


def test_reference_forces_and_the_report_section():
    s = sc.block(5)
    lin = LinearFEM(s.pos, s.tets, E, 0.45, s.constrained)
    u_lin = lin.solve(s.constrained_disp(0.1)).u
    nl = NeoHookeanFEM(s.pos, s.tets, E, 0.45, s.constrained)
    u_nl = nl.solve_path(s.constrained_disp(1.0), [0.1]).u[0.1]
    ref = reference_forces(s, 0.1, E, 0.45, lin, u_lin, nl, u_nl)
    assert 0 < ref["p2_linear"] < ref["p1_linear"]  # P1 locks: too stiff
    assert ref["reference"] == pytest.approx(ref["p2_linear"] * ref["p1_neohookean"] / ref["p1_linear"])
    results = {
        "pareto_strain": 0.1,
        "forces": [
            {"scene": "block", "nodes": s.n_nodes, "strain": 0.1, **ref, "live": {"XPBD": 1.1 * ref["reference"]}}
        ],
    }
    text = "\n".join(forces_section(results))
    assert "P2" in text and "1.100" in text
    assert forces_section({"pareto_strain": 0.1}) == []

"""Mass-spring reference of the study: critical time step (thesis eq. 2.2) and divergence reporting."""

import numpy as np

from chainsim.tools.study.mass_spring import MassSpring
from chainsim.tools.study.scenes import block


def setup(n=5, strain=0.05):
    s = block(n)
    ms = MassSpring(s.pos, s.tets, 3000.0, fixed=s.fixed)
    return s, ms, s.constrained, s.constrained_disp(strain)


def test_step_below_linear_bound_converges_to_finite_equilibrium():
    s, ms, c, d = setup()
    r = ms.solve(c, d, scheme="symplectic")
    assert r.status == "converged"
    assert np.all(np.isfinite(r.u))
    np.testing.assert_allclose(r.u[s.grabbed, 2], 0.05)
    # the pulled patch drags its neighbours up, the base stays put
    assert r.u[:, 2].max() > 0 and np.all(r.u[s.fixed] == 0)


def test_step_past_the_critical_one_is_reported_diverged_without_nan():
    s, ms, c, d = setup()
    ok = ms.solve(c, d, scheme="symplectic", max_steps=1)
    bound = ok.info["dt_bound"]
    r = ms.solve(c, d, scheme="symplectic", dt=3.0 * bound, max_steps=5000)
    assert r.status == "diverged"
    assert r.u is None
    assert np.isfinite(r.dt)


def test_linear_bound_separates_stable_from_unstable_steps():
    s, ms, c, d = setup(strain=0.01)
    bound = ms.solve(c, d, max_steps=1).info["dt_bound"]
    assert ms.solve(c, d, dt=0.8 * bound, max_steps=20000).status == "converged"
    assert ms.solve(c, d, dt=1.3 * bound, max_steps=20000).status == "diverged"


def test_eq_22_step_matches_its_formula():
    s, ms, c, d = setup()
    expected = np.sqrt(ms.mass.sum() / (ms.n * ms.k.max())) / np.pi
    assert np.isclose(ms.critical_dt_eq22(), expected)
    assert ms.critical_dt_eq22() > 0


def test_forward_euler_needs_a_much_smaller_step_than_symplectic():
    s, ms, c, d = setup()
    sym = ms.solve(c, d, scheme="symplectic", max_steps=1).info["dt_bound"]
    r = ms.solve(c, d, scheme="explicit", dt=0.8 * sym, max_steps=5000)
    assert r.status == "diverged" and r.u is None
    r = ms.solve(c, d, scheme="explicit", max_steps=200_000)
    assert r.status == "converged" and np.all(np.isfinite(r.u))


def test_youngs_modulus_over_six_orders_changes_time_scale_not_equilibrium():
    s = block(5)
    fields, dts = [], []
    for E in (1e2, 1e8):
        ms = MassSpring(s.pos, s.tets, E, fixed=s.fixed)
        r = ms.solve(s.constrained, s.constrained_disp(0.05), tol=1e-8)
        assert r.status == "converged" and np.all(np.isfinite(r.u))
        fields.append(r.u)
        dts.append(ms.critical_dt_eq22())
    np.testing.assert_allclose(fields[1], fields[0], atol=1e-6)
    assert np.isclose(dts[0] / dts[1], 1e3)  # dt ~ 1/sqrt(E), eq. (2.2)

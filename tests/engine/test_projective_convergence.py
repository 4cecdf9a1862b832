"""The projective body converges to the static equilibrium of its stated energy, computed here by an
independent minimisation (scipy's trust-region Newton on the energy of test_projective_energy), and
its stopping rule never ends a frame while the body is still far from that answer; a mesh too large
for the direct solver is switched to CG with a notice, or refused when direct was asked for.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_projective_energy import lame, minimise

from chainsim.systems.engine.bodies import projective
from chainsim.systems.engine.bodies.projective import ProjectiveBody
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.meshgen import tet_grid, triangulated_grid

PULL = 0.1  # of the block's height


def _block():
    """Unit cube of 3 x 3 x 3 cells, base fixed, the four top nodes round the centre grabbed."""
    pos, tets, _ = tet_grid(4, 4, 4, spacing=1.0 / 3.0)
    fixed = np.flatnonzero(pos[:, 2] < 1e-9)
    top = (pos[:, 2] > 1 - 1e-9) & (np.abs(pos[:, 0] - 0.5) < 0.2) & (np.abs(pos[:, 1] - 0.5) < 0.2)
    grab = np.flatnonzero(top)
    target = pos[grab] + [0.0, 0.0, PULL]
    return pos, tets, fixed, grab, target


@pytest.fixture(scope="module", params=[0.45, 0.499])
def pulled(request):
    nu = request.param
    pos, tets, fixed, grab, target = _block()
    mu, lam = lame(3000.0, nu)
    held = np.concatenate([fixed, grab])
    ref = minimise(pos, tets, mu, lam, held, np.concatenate([pos[fixed], target]))
    return nu, pos, tets, fixed, grab, target, ref


def _rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def test_statics_reaches_the_energys_minimum_and_stops_only_near_it(pulled):
    nu, pos, tets, fixed, grab, target, ref = pulled
    body = ProjectiveBody(pos, tets, E=3000.0, nu=nu, dynamic=False, fixed=fixed)
    body.grab(grab, target)
    # the contraction per iteration is about 1 - 2 mu / (2 mu + 3 lambda): 0.93 at nu 0.45, 0.9987 at 0.499
    bound = 30 if nu < 0.49 else 600
    errors = []
    for _ in range(bound):
        stats = body.step(1 / 60)
        err = _rms(body.positions, ref) / PULL
        errors.append(err)
        if stats.iterations < body.iterations:  # it stopped early: it must be close (tolerance 1e-6)
            assert err < 1e-4
            assert stats.residual <= body.tolerance
    assert errors[-1] < 0.01
    # with more frames it goes on towards the answer, to far below the 1 % asked
    for _ in range(bound):
        body.step(1 / 60)
    assert _rms(body.positions, ref) / PULL < 0.1 * errors[bound - 1] + 1e-6


def test_a_single_frame_of_many_iterations_gets_there_too(pulled):
    nu, pos, tets, fixed, grab, target, ref = pulled
    body = ProjectiveBody(pos, tets, E=3000.0, nu=nu, dynamic=False, fixed=fixed, iterations=10_000, tolerance=1e-8)
    body.grab(grab, target)
    stats = body.step(1 / 60)
    if nu < 0.49:
        assert _rms(body.positions, ref) / PULL < 1e-4
        assert stats.iterations < 10_000  # it stopped by itself
    else:  # contraction 0.9995 per iteration here: 10 000 take the error down by e^-5 only
        assert _rms(body.positions, ref) / PULL < 1e-2
        assert stats.iterations == 10_000 and stats.residual > body.tolerance  # and it says it is not there
    # the grab force is the energy's reaction: the reference's gradient on the grabbed nodes
    from test_projective_energy import gradient

    mu, lam = lame(3000.0, nu)
    want = gradient(ref, pos, tets, mu, lam)[grab].sum(axis=0)
    tol = 1e-3 if nu < 0.49 else 5e-2
    np.testing.assert_allclose(body.grab_force(), want, rtol=tol, atol=tol * np.abs(want).max())


def test_a_converged_frame_is_cheap():
    pos, tets, fixed, grab, target = _block()
    body = ProjectiveBody(pos, tets, E=3000.0, nu=0.45, dynamic=False, fixed=fixed)
    body.grab(grab, target)
    for _ in range(200):
        body.step(1 / 60)
    assert body.step(1 / 60).iterations == 1


def test_too_many_nodes_for_the_direct_solver_switches_to_cg_with_a_notice(monkeypatch):
    pos, tets, fixed, grab, target = _block()
    free = len(pos) - len(fixed)
    monkeypatch.setattr(projective, "DIRECT_MAX_NODES", free)
    assert ProjectiveBody(pos, tets, fixed=fixed).solver == "direct"  # at the limit: still direct
    monkeypatch.setattr(projective, "DIRECT_MAX_NODES", free - 1)
    body = ProjectiveBody(pos, tets, fixed=fixed, dynamic=False)
    assert body.solver == "cg"
    assert "cg" in body.notice and str(free) in body.notice and "\n" not in body.notice
    body.grab(grab, target)
    assert body.step(1 / 60).extra["notice"] == body.notice
    with pytest.raises(UserError, match="direct"):
        ProjectiveBody(pos, tets, fixed=fixed, solver="direct")
    assert ProjectiveBody(pos, tets, fixed=fixed, solver="cg").notice == ""
    # membranes follow the same rule
    tp, tris = triangulated_grid(5, 5, dim=3)[:2]
    monkeypatch.setattr(projective, "DIRECT_MAX_NODES", 10)
    assert ProjectiveBody(tp, triangles=tris).solver == "cg"
    with pytest.raises(UserError, match="direct"):
        ProjectiveBody(tp, triangles=tris, solver="direct")


def test_a_small_mesh_keeps_the_direct_solver_and_says_nothing():
    pos, tets, fixed, _, _ = _block()
    body = ProjectiveBody(pos, tets, fixed=fixed)
    assert (body.solver, body.notice) == ("direct", "")
    assert "notice" not in body.step(1 / 60).extra


@pytest.mark.parametrize("tolerance", [-1.0, float("nan")])
def test_a_bad_tolerance_is_refused(tolerance):
    pos, tets, fixed, _, _ = _block()
    with pytest.raises(UserError, match="tolerance"):
        ProjectiveBody(pos, tets, fixed=fixed, tolerance=tolerance)

"""Materials per tetrahedron in the projective and hybrid bodies (a layered tissue): the element
stiffness kernel against the textbook B^T C B V written here, a body of equal materials against the
body made with that material (bit for bit), and a two-layer block under a pull against the study's
neo-Hookean FEM (chainsim.tools.study.fem_nonlinear, its own element code and Newton solver), whose
energy for two materials is the sum of one solver per layer over the same nodes."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from chainsim.systems.engine.bodies.factory import make_body
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels.twolevel import tet_stiffness
from chainsim.tools.study import surgical
from chainsim.tools.study.fem_nonlinear import NeoHookeanFEM

DT = 1.0 / 60.0


def _reference_stiffness(D, vol, mu, lam):
    """Linear elasticity's element matrix V B^T C B, the strain in Voigt form (engineering shear)."""
    K = np.zeros((len(D), 12, 12))
    for t in range(len(D)):
        B = np.zeros((6, 12))
        for a in range(4):
            gx, gy, gz = D[t, a]
            B[:, 3 * a : 3 * a + 3] = [[gx, 0, 0], [0, gy, 0], [0, 0, gz], [gy, gx, 0], [0, gz, gy], [gz, 0, gx]]
        C = np.zeros((6, 6))
        C[:3, :3] = lam[t]
        C[np.arange(3), np.arange(3)] += 2.0 * mu[t]
        C[np.arange(3, 6), np.arange(3, 6)] = mu[t]
        K[t] = vol[t] * B.T @ C @ B
    return K


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 12).flatmap(lambda t: st.tuples(
    arrays(np.float64, (t, 4, 3), elements=st.floats(-5, 5, allow_nan=False)),
    arrays(np.float64, (t,), elements=st.floats(0.0, 3.0, allow_nan=False)),
    arrays(np.float64, (t,), elements=st.floats(0.0, 1e6, allow_nan=False)),
    arrays(np.float64, (t,), elements=st.floats(0.0, 1e7, allow_nan=False)),
)))  # fmt: skip
def test_element_stiffness_per_element_is_the_textbook_matrix(case):
    D, vol, mu, lam = case
    K = tet_stiffness(D, vol, mu, lam)
    ref = _reference_stiffness(D, vol, mu, lam)
    scale = max(float(np.abs(ref).max()), 1e-300)
    np.testing.assert_allclose(K, ref, rtol=0, atol=1e-12 * scale)
    # each element's matrix is its own: a change of one element's material changes that one alone
    if len(D) > 1:
        mu2 = mu.copy()
        mu2[0] += 1.0
        np.testing.assert_array_equal(tet_stiffness(D, vol, mu2, lam)[1:], K[1:])


def _pull(body, held, rest, offset, frames):
    for _ in range(frames):
        body.grab(held, rest[held] + offset)
        body.step(DT)
    return body.positions.copy()


@pytest.mark.parametrize("model", ["hybrid", "projective"])
def test_equal_materials_everywhere_give_exactly_the_one_material_body(model):
    b = surgical.block(5.0)
    kw = dict(tets=b.tets, fixed=b.fixed, E=2.5e4, nu=0.45, unit=1e-3)
    one = make_body(model, b.pos, **kw)
    many = make_body(model, b.pos, **kw)
    T = len(b.tets)
    many.set_materials(np.full(T, 2.5e4), np.full(T, 0.45))
    offset = np.array([1.5, 0.0, 2.0])
    np.testing.assert_array_equal(_pull(many, b.grabbed, b.pos, offset, 8), _pull(one, b.grabbed, b.pos, offset, 8))


def test_bad_materials_are_refused_in_one_line_naming_what_is_wrong():
    b = surgical.block(5.0)
    body = make_body("hybrid", b.pos, tets=b.tets, fixed=b.fixed, unit=1e-3)
    T = len(b.tets)
    with pytest.raises(UserError, match=r"one E and one nu per tetrahedron"):
        body.set_materials(np.full(T - 1, 1e4), np.full(T - 1, 0.4))
    with pytest.raises(UserError, match=r"nu: Poisson's ratio"):
        body.set_materials(np.full(T, 1e4), np.full(T, 0.5))
    with pytest.raises(UserError, match=r"E: Young's modulus"):
        body.set_materials(np.full(T, -1.0), np.full(T, 0.4))


class _TwoMaterialFEM(NeoHookeanFEM):
    """The study's neo-Hookean FEM with two materials: its energy, forces and tangent are sums over
    elements, so the sum of one solver per material over the same nodes is the layered body's."""

    def __init__(self, pos, tets, parts, constrained):
        super().__init__(pos, tets, 1.0, 0.3, constrained)
        self.parts = [NeoHookeanFEM(pos, tets[mask], E, nu, constrained) for mask, E, nu in parts]

    def energy(self, u_flat):
        return sum(p.energy(u_flat) for p in self.parts)

    def residual_and_tangent(self, u_flat, want_tangent=True):
        out = [p.residual_and_tangent(u_flat, want_tangent) for p in self.parts]
        r = sum(o[0] for o in out)
        return r, (sum(o[1] for o in out) if want_tangent else None)


def test_a_two_layer_block_under_a_pull_matches_the_neo_hookean_fem():
    """A stiff 4 mm top layer (40 kPa, the dermis of docs/tissue-layers.md) over a soft base (10.7 kPa)
    on the study's 30 x 30 x 20 mm block, its top patch lifted 2 mm and pushed 1 mm sideways: the layered
    body's settled shape against the FEM with the same two materials, and against the body with one
    material, which the FEM tells apart from it."""
    b = surgical.block(2.5)
    top = b.pos[b.tets].mean(axis=1)[:, 2] > 16.0
    E = np.where(top, 4.0e4, 1.07e4)
    nu = np.full(len(b.tets), 0.45)
    pull = np.array([1.0, 0.0, 2.0])
    c = np.unique(np.concatenate([b.fixed, b.grabbed]))
    disp = np.zeros((len(c), 3))
    disp[np.isin(c, b.grabbed)] = pull
    parts = [(top, 4.0e4, 0.45), (~top, 1.07e4, 0.45)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = _TwoMaterialFEM(b.pos * 1e-3, b.tets, parts, c).solve_path(disp * 1e-3, [1.0])
    assert res.status == "converged"
    ref = res.u[1.0] * 1e3

    def settled(materials):
        body = make_body("hybrid", b.pos, tets=b.tets, fixed=b.fixed, E=1.6e4, nu=0.45, unit=1e-3)
        if materials:
            body.set_materials(E, nu)
        return _pull(body, b.grabbed, b.pos, pull, 240) - b.pos

    def rms(u):
        return float(np.sqrt(np.mean(np.sum((u - ref) ** 2, axis=1))) / np.linalg.norm(pull))

    layered, single = rms(settled(True)), rms(settled(False))
    assert layered < 0.02, f"layered body {layered:.4f} of the pull from the FEM"
    # the layers matter here: one material (the whole tissue's 16 kPa) is ten times further off
    assert single > 5.0 * layered, f"one material {single:.4f}, layered {layered:.4f}"

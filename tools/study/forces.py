"""The study's force reference: the grab reaction a scene needs, from a mesh that does not lock.

Linear P1 tetrahedra lock at the study's nu = 0.45, so their grab reaction is too large even where
their displacement field is fine. The reference is therefore linear elasticity on quadratic (P2)
tetrahedra of the same mesh (`fem_quadratic`), corrected for large strain by the ratio of the
neo-Hookean to the linear P1 reaction on that mesh (both lock alike, so their ratio is the
nonlinear part):  F_ref = F_P2 * F_nl,P1 / F_lin,P1.  Every figure is the component along the
scene's pull direction, in newtons (scene lengths are metres, E in pascals).
"""

from __future__ import annotations

import numpy as np

from .fem_quadratic import QuadraticFEM

REFERENCE_NAME = "linear P2 (10-node) tetrahedra x neo-Hookean/linear P1 ratio, same mesh"


def reaction_along(scene, internal: np.ndarray) -> float:
    """Sum over the grabbed nodes of the internal force (N, 3), along the pull: the force the grab applies."""
    return float(internal[scene.grabbed].sum(axis=0) @ scene.direction)


def reference_forces(scene, strain: float, E: float, nu: float, lin, u_lin: np.ndarray, nl, u_nl) -> dict:
    """Grab reactions at `strain` by P1 linear, P1 neo-Hookean (when u_nl is given), P2 linear and the
    composite reference; `lin` is the scene's LinearFEM, `nl` its NeoHookeanFEM (or None)."""
    p1 = reaction_along(scene, (lin.K @ u_lin.ravel()).reshape(-1, 3))
    q = QuadraticFEM(scene.pos, scene.tets, E, nu, scene.constrained)
    u2 = q.solve(scene.constrained_disp(strain))
    p2 = float(q.reaction(u2, scene.grabbed) @ scene.direction)
    out: dict[str, float | str] = {"p1_linear": p1, "p2_linear": p2, "p2_nodes": len(q.pos2)}
    if nl is not None and u_nl is not None:
        r, _ = nl.residual_and_tangent(np.asarray(u_nl).ravel(), want_tangent=False)
        p1_nl = reaction_along(scene, r.reshape(-1, 3))
        out.update({"p1_neohookean": p1_nl, "reference": p2 * p1_nl / p1, "reference_name": REFERENCE_NAME})
    else:
        out.update({"reference": p2, "reference_name": "linear P2 (10-node) tetrahedra, same mesh"})
    return out

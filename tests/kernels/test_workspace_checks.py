"""A workspace remembers the mesh arrays it has checked; different arrays are always checked again."""

from __future__ import annotations

import numpy as np
import pytest

from chainsim.systems.engine import meshgen
from chainsim.systems.engine.kernels.chainmail import cascade, make_workspace, material_arrays
from chainsim.systems.engine.kernels.graph import build_graph


def test_new_arrays_are_checked_even_after_a_good_call_with_the_same_workspace():
    pos, links = meshgen.grid((5, 5))
    g = build_graph(len(pos), links)
    amin, amax, beta = material_arrays(len(links), 0.8, 1.2, 0.1)
    ws = make_workspace(len(pos))
    rest = pos.copy()
    cascade(rest, pos, g, amin, amax, beta, np.array([12]), np.array([[2.5, 2.5]]), workspace=ws)
    with pytest.raises(ValueError, match="amin must be a per-link"):
        cascade(rest, pos, g, amin[:-1].copy(), amax, beta, np.array([12]), np.array([[2.6, 2.5]]), workspace=ws)
    other_pos, other_links = meshgen.grid((5, 4))
    with pytest.raises(ValueError, match="graph has"):
        cascade(
            rest,
            pos,
            build_graph(len(other_pos), other_links),
            amin,
            amax,
            beta,
            np.array([12]),
            np.array([[2.6, 2.5]]),
            workspace=ws,
        )
    with pytest.raises(ValueError, match="rest must match pos"):
        cascade(rest.astype(np.float32), pos, g, amin, amax, beta, np.array([12]), np.array([[2.6, 2.5]]), workspace=ws)
    # the remembered mesh still works after the refusals
    order, _ = cascade(rest, pos, g, amin, amax, beta, np.array([12]), np.array([[3.0, 2.5]]), workspace=ws)
    assert order[0] == 12

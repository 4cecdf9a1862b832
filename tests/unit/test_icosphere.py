"""The renderer's icosphere (built without trimesh, so a window starts sooner) is trimesh's, vertex
for vertex and triangle for triangle: markers and points draw the same pixels as before."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from chainsim.game.render.icosphere import icosphere


@pytest.mark.parametrize("subdiv", [0, 1, 2, 3])
def test_the_icosphere_is_trimeshs(subdiv):
    theirs = trimesh.creation.icosphere(subdivisions=subdiv, radius=1.0)
    v, f = icosphere(subdiv)
    assert v.dtype == np.float64 and f.dtype == np.int64
    np.testing.assert_array_equal(v, np.asarray(theirs.vertices))
    np.testing.assert_array_equal(f, np.asarray(theirs.faces))

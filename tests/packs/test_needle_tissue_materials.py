"""The needle packs' tissue deforms with each layer's own material: every tetrahedron of the shipped
volumes takes the E and nu of its layer's [tissue_layers] table (read here from pack.toml and the mesh
file directly), under the pack's model and after a switch to another physical model."""

from __future__ import annotations

import tomllib

import esper
import meshio
import numpy as np
import pytest
from needle_insertion import ASSETS

from chainsim.game.app.headless import build_app
from chainsim.systems.procedures.needle.tissue import NeedleTissueScene
from chainsim.systems.tissue.deformable import Deformable, use_model


def _expected_two_mu(pack: str, mesh_file: str) -> np.ndarray:
    """2 mu = E / (1 + nu) of each tetrahedron, from its cell data `layer` and the layer tables."""
    manifest = tomllib.loads((ASSETS / pack / "pack.toml").read_text())
    by_number = {
        int(t["mesh_layer"]): (1e3 * t["E_kPa"], t.get("nu", 0.45)) for t in manifest["tissue_layers"].values()
    }
    m = meshio.read(ASSETS / pack / "meshes" / mesh_file)
    layer = np.concatenate([b for c, b in zip(m.cells, m.cell_data["layer"]) if c.type == "tetra"])
    return np.array([by_number[int(k)][0] / (1.0 + by_number[int(k)][1]) for k in layer])


@pytest.mark.parametrize("pack", ["mental-block", "prp"])
def test_each_tetrahedron_deforms_with_its_layers_modulus(pack):
    app = build_app(pack, save="a test saves nothing")
    try:
        with app.active():
            scene = app.resource(NeedleTissueScene)
            for body in scene.bodies:
                d = esper.component_for_entity(body.entity, Deformable)
                want = _expected_two_mu(pack, f"{body.name}.vtu")
                assert len(np.unique(np.round(want))) >= 3  # the layers differ: the check can tell them apart
                for model in (d.model_used, "projective"):
                    if model != d.model_used:
                        use_model(d, model)
                    np.testing.assert_allclose(d.body.w_arap / d.body.vol, want, rtol=1e-12)
    finally:
        app.close()

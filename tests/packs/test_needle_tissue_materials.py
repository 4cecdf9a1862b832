"""The needle packs' tissue deforms with each layer's own material: every tetrahedron of the shipped
volumes takes the E and nu of its layer's [tissue_layers] table (read here from pack.toml and the mesh
file directly), under the pack's model and after a switch to another physical model; and the tip presses
the skin over the force model's punch, not over one face of the mesh."""

from __future__ import annotations

import tomllib

import esper
import meshio
import numpy as np
import pytest
from needle_insertion import ASSETS

from chainsim.components.resources import PendingInput
from chainsim.game.trainer.headless import build_app
from chainsim.systems.procedures.needle.insertion import straight_insertion
from chainsim.systems.procedures.needle.tissue import NeedleTissue, NeedleTissueScene
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
                for model in (d.body.model_used, "projective"):
                    if model != d.body.model_used:
                        use_model(d, model)
                    np.testing.assert_allclose(d.body.model_body.w_arap / d.body.model_body.vol, want, rtol=1e-12)
                use_model(d, "xpbd")  # one material per body: the model line says the layers' are not used
                assert "xpbd keeps one E and nu for the whole body" in d.body.model_reason
    finally:
        app.close()


@pytest.mark.parametrize("pack", ["mental-block", "prp"])
def test_the_tip_presses_the_skin_over_the_force_models_punch(pack):
    """Before the skin gives, every free skin node within contact_radius_mm of where the needle meets the
    skin (the flat punch the stiffness term assumes; nodes from the mesh file's skin triangles and pinned
    points) goes with the tip, not only the face the needle crosses."""
    manifest = tomllib.loads((ASSETS / pack / "pack.toml").read_text())
    radius = float(manifest["needle_tissue"]["contact_radius_mm"])
    events, _, _ = straight_insertion(ASSETS / pack, manifest)
    app = build_app(pack, save="a test saves nothing")
    try:
        app.resource(PendingInput).extend(events)
        scene = app.resource(NeedleTissueScene)
        pressed = []
        for _ in range(400):
            app.update(app.time.dt)
            with app.active():
                [(_, nt)] = esper.get_component(NeedleTissue)
                if nt.punctured:
                    break
                if nt.contact and nt.tent > 0:
                    c = nt.crossings[0]
                    body = scene.bodies[c.body]
                    d = esper.component_for_entity(body.entity, Deformable)
                    pressed.append((body.name, c.point.copy(), c.nodes.copy(), d.body.positions - d.body.rest))
        assert len(pressed) >= 3, "the tip pressed the skin for a few frames before it gave"
        name, point, face, moved = pressed[-1]
        m = meshio.read(ASSETS / pack / "meshes" / f"{name}.vtu")
        skin = np.unique(m.cells_dict["triangle"])
        skin = skin[m.point_data["fixed"][skin] == 0]
        under = skin[np.linalg.norm(m.points[skin] - point, axis=1) <= radius]
        assert len(under), "nodes lie under the punch"  # on prp's cheek more than the crossed face's three
        tent = np.linalg.norm(moved[face], axis=1)
        assert tent.min() > 1.0  # the crossed face went in with the tip
        np.testing.assert_allclose(np.linalg.norm(moved[under], axis=1), tent.mean(), rtol=1e-6)
    finally:
        app.close()

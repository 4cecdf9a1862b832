"""One declaration of each model's parameters drives the bodies, `make_body`, the manifest and the docs;
`make_body` builds every model by name and refuses an unknown one in one line that lists them."""

from __future__ import annotations

import inspect
from pathlib import Path

import numpy as np
import pytest

import chainsim.game.packs.declarations  # noqa: F401  (registers the manifest sections)
from chainsim.components.registry import COMPONENTS, SECTIONS, load_all
from chainsim.game.cli.commands import docs as docs_command
from chainsim.systems import manifest_modules
from chainsim.systems.engine import meshgen, model_params
from chainsim.systems.engine.bodies.chainmail import ChainMailBody
from chainsim.systems.engine.bodies.factory import make_body
from chainsim.systems.engine.bodies.hybrid import HybridBody
from chainsim.systems.engine.bodies.projective import ProjectiveBody
from chainsim.systems.engine.bodies.surface import SurfaceChainMailBody
from chainsim.systems.engine.bodies.xpbd import XPBDBody
from chainsim.systems.engine.errors import UserError

BODIES = {
    "chainmail": ChainMailBody,
    "xpbd": XPBDBody,
    "projective": ProjectiveBody,
    "hybrid": HybridBody,
    "surface": SurfaceChainMailBody,
}
DOC = Path(__file__).resolve().parents[2] / "docs" / "choosing-a-model.md"


def _block():
    rest, tets, _ = meshgen.tet_grid(4, 4, 3, spacing=1.0)
    fixed = np.flatnonzero(rest[:, 2] == 0.0)
    top = int(np.argmax(rest[:, 2] * 100 + rest[:, 0] + rest[:, 1]))
    return rest, {"tets": tets}, fixed, top


def _sheet():
    rest, tris, _ = meshgen.triangulated_grid(5, 5, spacing=1.0, dim=3)
    fixed = np.flatnonzero(rest[:, 1] == 0.0)
    top = int(np.argmax(rest[:, 1] * 100 + rest[:, 0]))
    return rest, {"triangles": tris}, fixed, top


def test_every_model_has_a_declaration_and_a_body():
    assert model_params.MODELS == tuple(BODIES)
    for model, cls in BODIES.items():
        assert cls.model == model


@pytest.mark.parametrize("model", model_params.MODELS)
def test_make_body_builds_each_model_and_it_follows_a_grab(model):
    rest, mesh, fixed, top = _sheet() if model == "surface" else _block()
    body = make_body(model, rest, fixed=fixed, **mesh)
    assert type(body) is BODIES[model]
    target = rest[top] + [0.0, 0.0, 0.2]  # within what SurfaceChainMail allows from its pinned rim
    body.grab([top], target[None])
    for _ in range(3):
        body.step(1.0 / 60.0)
    np.testing.assert_allclose(body.positions[top], target, atol=1e-9)
    moved = np.flatnonzero(np.linalg.norm(body.positions - rest, axis=1) > 1e-6)
    assert len(moved) > 1 and top in moved  # the body, not only the grabbed element, moved
    np.testing.assert_array_equal(body.positions[fixed], rest[fixed])


def test_an_unknown_model_is_refused_in_one_line_naming_every_model():
    rest, mesh, _, _ = _block()
    with pytest.raises(UserError) as e:
        make_body("Chainmail", rest, **mesh)
    msg = str(e.value)
    assert "\n" not in msg and "'Chainmail'" in msg
    for model in model_params.MODELS:
        assert model in msg


@pytest.mark.parametrize("model", model_params.MODELS)
def test_the_body_constructors_take_their_defaults_from_the_declaration(model):
    sig = inspect.signature(BODIES[model].__init__).parameters
    for p in model_params.MODEL_PARAMS[model]:
        assert p.name in sig, f"{model}: the body does not take {p.name}"
        assert sig[p.name].default == p.default, f"{model}.{p.name}"


@pytest.mark.parametrize(
    "model, settings, word",
    [
        ("chainmail", {"alpha_min": 1.5}, "alpha_min: must be in [0, 1]"),
        ("chainmail", {"beta": -0.1}, "beta: must be >= 0"),
        ("chainmail", {"relax": 2.5}, "relax: expected a whole number"),
        ("chainmail", {"order": "sideways"}, "order: expected one of"),
        ("surface", {"alpha_max": 0.5}, "alpha_max: must be >= 1"),
        ("xpbd", {"substeps": 0}, "substeps: must be in [1, 1000]"),
        ("projective", {"cg_iterations": 0}, "cg_iterations"),
        ("hybrid", {"start": "sideways"}, "start: expected one of none, chainmail, linear"),
    ],
)
def test_make_body_checks_settings_against_the_declaration(model, settings, word):
    rest, mesh, _, _ = _sheet() if model == "surface" else _block()
    with pytest.raises(UserError, match=word.replace("[", r"\[").replace("]", r"\]")):
        make_body(model, rest, **mesh, **settings)


def test_per_link_limits_reach_a_chainmail_body_as_given():
    rest, mesh, fixed, _ = _block()
    links = meshgen.links_from_cells(mesh["tets"])
    amin = np.linspace(0.5, 0.9, len(links))
    amax = np.linspace(1.1, 1.6, len(links))
    beta = np.linspace(0.0, 0.3, len(links))
    body = make_body("chainmail", rest, links=links, fixed=fixed, alpha_min=amin, alpha_max=amax, beta=beta)
    assert body.amin is amin and body.amax is amax and body.beta is beta
    with pytest.raises(UserError, match="alpha_min: must be in"):
        make_body("chainmail", rest, links=links, alpha_min=np.r_[amin[:-1], 1.5])
    with pytest.raises(UserError, match="one value per link"):
        make_body("chainmail", rest, links=links, alpha_min=amin[:-1])


def _registry_field(table: str, key: str):
    load_all(manifest_modules())
    schema = SECTIONS["materials"] if table == "materials" else COMPONENTS["deformable"]
    return schema.field(key)


@pytest.mark.parametrize(
    "model, key, table",
    [(m, k, t) for m, keys in model_params.PACK_TABLE.items() for k, t in keys.items()],
)
def test_the_manifest_keys_are_the_declared_parameters(model, key, table):
    p = model_params.params(model)[key]
    f = _registry_field(table, key)
    assert f is not None, f"[{table}] has no key {key}"
    assert f.kind == p.kind and f.default == p.manifest_default
    assert tuple(f.choices) == tuple(p.choices)
    # the pack's range is the body's, widened only to the pack's "the model's own" default
    lo = p.min if p.min is None or p.manifest_default >= p.min else p.manifest_default
    assert f.min is None if p.min is None else f.min <= lo
    assert f.max is None if p.max is None else f.max <= p.max
    assert p.help.rstrip(".").split(":")[0] in f.help


def test_docs_list_the_declared_parameters(capsys):
    text = model_params.markdown()
    for model, ps in model_params.MODEL_PARAMS.items():
        assert f"### `{model}`" in text
        for p in ps:
            assert f"| `{p.name}` |" in text
    assert text in DOC.read_text(encoding="utf-8"), "regenerate the tables: chainsim docs models"
    args = docs_command.add_parser(__import__("argparse").ArgumentParser().add_subparsers()).parse_args(["models"])
    assert docs_command.run(args) == 0
    assert capsys.readouterr().out == text

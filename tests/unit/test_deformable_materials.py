"""Per-link materials from pack.toml to the kernel: a body of two materials (a `regions` box of another
[materials] entry) moves with both limits, and the arrays the cascade receives are the ones the
manifest declares, link by link, built once by the deformable component and handed to the body."""

from __future__ import annotations

import textwrap
from pathlib import Path

import esper
import numpy as np
import pytest

from chainsim.game.trainer.headless import build_app
from chainsim.systems.engine.bodies import chainmail as chainmail_body
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.kernels.chainmail import cascade
from chainsim.systems.engine.kernels.graph import build_graph
from chainsim.systems.tissue.deformable import Deformable
from chainsim.systems.tissue.events import GrabRequest

SOFT = (0.5, 1.8, 0.4)
STIFF = (0.95, 1.05, 0.02)
#: the upper half of the 4 mm block (z from 0 to 2 in its local frame, which runs -2..2)
BOX = (-10.0, -10.0, 0.0, 10.0, 10.0, 10.0)

PACK = """
[pack]
name = "mattest"
format = 1

[meshes.block]
primitive = "tet_block"
extents = [4.0, 4.0, 4.0]
resolution = [4.0, 4.0, 4.0]

[materials.soft]
alpha_min = {soft[0]}
alpha_max = {soft[1]}
beta = {soft[2]}
relax = 0

[materials.stiff]
alpha_min = {stiff[0]}
alpha_max = {stiff[1]}
beta = {stiff[2]}
relax = 0

[entities.body.mesh]
mesh = "block"
material = "soft"

[entities.body.deformable]
model = "{model}"
{extra}
"""


def make_pack(tmp_path: Path, model: str = "chainmail", extra: str = "") -> str:
    root = tmp_path / "mattest"
    root.mkdir(exist_ok=True)
    text = PACK.format(soft=SOFT, stiff=STIFF, model=model, extra=extra)
    (root / "pack.toml").write_text(textwrap.dedent(text), encoding="utf-8")
    return str(root)


REGIONS = f'regions = ["stiff"]\nregion_boxes = {list(BOX)}\n'


def deformable(app) -> Deformable:
    with app.active():
        ((_, d),) = esper.get_component(Deformable)
        return d


def declared(rest: np.ndarray, links: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the manifest says, link by link: stiff where the link's midpoint lies in BOX, soft elsewhere."""
    mid = 0.5 * (rest[links[:, 0]] + rest[links[:, 1]])
    box = np.asarray(BOX)
    inside = np.all((mid >= box[:3]) & (mid <= box[3:]), axis=1)
    return tuple(np.where(inside, STIFF[k], SOFT[k]) for k in range(3))


def test_two_materials_reach_the_kernel_link_by_link(tmp_path, monkeypatch):
    received = []
    real = chainmail_body.cascade

    def spy(rest, pos, graph, amin, amax, beta, *args, **kw):
        received.append((amin, amax, beta))
        return real(rest, pos, graph, amin, amax, beta, *args, **kw)

    monkeypatch.setattr(chainmail_body, "cascade", spy)
    app = build_app(make_pack(tmp_path, extra=REGIONS))
    try:
        d = deformable(app)
        want = declared(d.body.rest, d.body.graph.links)
        assert 0 < np.count_nonzero(want[0] == STIFF[0]) < len(want[0])  # both materials are on the body
        # the limits built at spawn are the ChainMail body's own arrays, not a copy cut to their first value
        model = d.body.model_body
        assert all(a is b for a, b in zip((model.amin, model.amax, model.beta), d.body.base_limits))
        top = int(np.argmax(d.body.rest[:, 2] + 1e-3 * d.body.rest[:, 0]))
        app.events.emit(GrabRequest("body", [top], d.body.rest[top] + [0.0, 0.0, 3.0], frame="local"))
        app.run_steps(1)
        assert len(received) == 1
        for got, exp in zip(received[0], want):
            np.testing.assert_array_equal(got, exp)
    finally:
        app.close()


def test_a_body_of_two_materials_moves_as_a_plain_cascade_with_both_limits(tmp_path):
    app = build_app(make_pack(tmp_path, extra=REGIONS))
    try:
        d = deformable(app)
        rest, links = d.body.rest.copy(), d.body.graph.links.copy()
        grab = int(np.argmax(d.body.rest[:, 2] + 1e-3 * d.body.rest[:, 0]))
        target = rest[grab] + [0.0, 0.0, 3.0]
        app.events.emit(GrabRequest("body", [grab], target, frame="local"))
        app.run_steps(1)
        got = d.body.positions.copy()
    finally:
        app.close()

    def reference(amin, amax, beta):
        pos = rest.copy()
        cascade(rest, pos, build_graph(len(rest), links), amin, amax, beta, np.array([grab]), target[None])
        return pos

    mixed = reference(*declared(rest, links))
    np.testing.assert_allclose(got, mixed, atol=1e-12)
    # both limits act: the soft material alone, or the stiff one alone, moves the block otherwise
    m = len(links)
    soft_only = reference(*(np.full(m, v) for v in SOFT))
    stiff_only = reference(*(np.full(m, v) for v in STIFF))
    assert np.abs(got - soft_only).max() > 1e-3
    assert np.abs(got - stiff_only).max() > 1e-3


def test_surface_chainmail_gets_the_per_link_limits(tmp_path):
    text = make_pack(tmp_path, model="surface", extra=REGIONS)
    root = Path(text)
    toml = (root / "pack.toml").read_text()
    toml = toml.replace('primitive = "tet_block"', 'primitive = "grid"').replace(
        "extents = [4.0, 4.0, 4.0]\nresolution = [4.0, 4.0, 4.0]",
        "extents = [4.0, 4.0, 0.0]\nresolution = [4.0, 4.0, 1.0]",
    )
    # the sheet lies in z = 0: a box over its x > 0 half
    toml = toml.replace(f"region_boxes = {list(BOX)}", "region_boxes = [0.0, -10.0, -1.0, 10.0, 10.0, 1.0]")
    (root / "pack.toml").write_text(toml)
    app = build_app(text)
    try:
        d = deformable(app)
        assert d.body.model_used == "surface"
        plane = d.body.model_body.plane
        links = d.body.graph.links
        mid = 0.5 * (d.body.rest[links[:, 0]] + d.body.rest[links[:, 1]])
        inside = mid[:, 0] >= 0.0
        assert 0 < inside.sum() < len(links)
        np.testing.assert_array_equal(plane.amin, np.where(inside, STIFF[0], SOFT[0]))
        np.testing.assert_array_equal(plane.beta, np.where(inside, STIFF[2], SOFT[2]))
    finally:
        app.close()


@pytest.mark.parametrize(
    "extra, words",
    [
        ('regions = ["stiff"]\nregion_boxes = [0.0, 0.0, 0.0]\n', "region_boxes"),
        ('regions = ["nope"]\nregion_boxes = [0, 0, 0, 1, 1, 1]\n', "no material 'nope'"),
        ('regions = ["stiff"]\nregion_boxes = [1, 0, 0, 0, 1, 1]\n', "min <= max"),
    ],
)
def test_regions_that_cannot_work_are_refused_naming_the_key(tmp_path, extra, words):
    with pytest.raises(UserError, match=words):
        build_app(make_pack(tmp_path, extra=extra)).close()

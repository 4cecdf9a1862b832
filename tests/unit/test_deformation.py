"""Deformable bodies in the engine: spawn from a pack, grab/release requests, frames, anchors, dirty ids,
the digest, default bodies from `simulation.kind`, and the absence of the system in rigid scenes."""

from __future__ import annotations

import textwrap
from pathlib import Path

import esper
import numpy as np
import pytest

from chainsim.components.digest import world_digest
from chainsim.game.trainer.headless import build_app
from chainsim.systems.engine.errors import UserError
from chainsim.systems.tissue.deformable import Deformable, Pull
from chainsim.systems.tissue.events import Deformed, GrabRequest, ReleaseRequest

PACK_HEAD = """
[pack]
name = "deftest"
format = 1

[meshes.sheet]
primitive = "grid"
extents = [10.0, 10.0, 0.0]
resolution = [10.0, 10.0, 1.0]

[meshes.block]
primitive = "tet_block"
extents = [4.0, 4.0, 4.0]
resolution = [4.0, 4.0, 4.0]

[materials.rigid]
alpha_min = 1.0
alpha_max = 1.0
beta = 0.0
relax = 0

[materials.medium]
alpha_min = 0.8
alpha_max = 1.2
beta = 0.1
relax = 0
"""


def make_pack(tmp_path: Path, body: str) -> str:
    root = tmp_path / "deftest"
    root.mkdir(exist_ok=True)
    (root / "pack.toml").write_text(textwrap.dedent(PACK_HEAD) + textwrap.dedent(body), encoding="utf-8")
    return str(root)


def body(app, name="body") -> tuple[int, Deformable]:
    from chainsim.components.resources import EntityIndex

    ent = app.resource(EntityIndex)[name]
    with app.active():
        return ent, esper.component_for_entity(ent, Deformable)


SHEET = """
[entities.body.mesh]
mesh = "sheet"
material = "{material}"
[entities.body.deformable]
"""


def test_rigid_scene_gets_no_deformation_system():
    app = build_app("loop-demo")
    try:
        assert "deformation" not in app.systems("simulation")
        assert "pull" not in app.systems("simulation")
    finally:
        app.close()


def test_spawn_builds_the_chainmail_object_from_the_render_mesh(tmp_path):
    app = build_app(make_pack(tmp_path, SHEET.format(material="medium")))
    try:
        assert "deformation" in app.systems("simulation")
        _, d = body(app)
        from chainsim.components.resources import PackResource

        mesh = app.resource(PackResource).pack.mesh("sheet")
        np.testing.assert_array_equal(d.body.positions, mesh.vertices)  # same vertex order as the renderer's mesh
        np.testing.assert_array_equal(d.body.rest, mesh.vertices)
        assert d.body.graph.n_links == len(mesh.edge_links())
        assert np.all(d.body.limits[0] == 0.8) and np.all(d.body.limits[1] == 1.2) and np.all(d.body.limits[2] == 0.1)
        assert d.body.relax_iterations == 0 and d.body.version == 0 and len(d.body.dirty) == 0
    finally:
        app.close()


def test_grab_moves_the_element_emits_deformed_and_marks_dirty(tmp_path):
    app = build_app(make_pack(tmp_path, SHEET.format(material="medium")))
    try:
        ent, d = body(app)
        seen = app.events.reader(Deformed)
        target = d.body.rest[60] + [0.0, 0.0, 4.0]
        app.events.emit(GrabRequest("body", [60], target, frame="local"))
        app.run_steps(1)
        np.testing.assert_allclose(d.body.positions[60], target)
        moved = np.flatnonzero(np.any(d.body.positions != d.body.rest, axis=1))
        assert 60 in moved and len(moved) > 1
        assert set(moved.tolist()) <= set(d.body.dirty.tolist())
        assert set(d.body.dirty.tolist()) == set(d.body.last_order.tolist())
        evs = seen.read()
        assert len(evs) == 1 and evs[0].entity == ent and evs[0].moved_count == len(d.body.last_order)
        assert d.body.version == 1 and d.body.held.tolist() == [60]
        # every moved element sits in the valid region of its sponsor (thesis 5.2.2), nothing else moved
        for e, s in zip(d.body.last_order[1:], d.body.last_sponsor[1:]):
            lo, hi = _box(d.body.rest, d.body.positions, e, s, 0.8, 1.2, 0.1)
            assert np.all(d.body.positions[e] >= lo - 1e-9) and np.all(d.body.positions[e] <= hi + 1e-9)
    finally:
        app.close()


def _box(rest, pos, e, s, amin, amax, beta):
    dv = rest[e] - rest[s]
    ad = np.abs(dv)
    other = ad.sum() - ad
    lo_off, hi_off = amin * ad - beta * other, amax * ad + beta * other
    return (np.where(dv >= 0, pos[s] + lo_off, pos[s] - hi_off), np.where(dv >= 0, pos[s] + hi_off, pos[s] - lo_off))


def test_rigid_material_translates_and_world_targets_use_the_transform(tmp_path):
    app = build_app(
        make_pack(
            tmp_path,
            SHEET.format(material="rigid")
            + """
[entities.body.transform]
position = [100.0, 0.0, 0.0]
""",
        )
    )
    try:
        _, d = body(app)
        world_target = d.body.rest[5] + [100.0, 0.0, 3.0]
        app.events.emit(GrabRequest("body", [5], world_target))  # world frame is the default
        app.run_steps(1)
        np.testing.assert_allclose(d.body.positions, d.body.rest + [0.0, 0.0, 3.0], atol=1e-12)
    finally:
        app.close()


def test_fixed_box_pins_elements(tmp_path):
    app = build_app(
        make_pack(
            tmp_path,
            SHEET.format(material="rigid")
            + """
fixed_box = [-100.0, -100.0, -1.0, -4.0, 100.0, 1.0]
""",
        )
    )
    try:
        _, d = body(app)
        pinned = d.body.rest[:, 0] <= -4.0
        assert pinned.sum() > 0 and np.array_equal(d.body.fixed, pinned)
        app.events.emit(
            GrabRequest(
                "body",
                [int(np.argmax(d.body.rest[:, 0]))],
                d.body.rest[np.argmax(d.body.rest[:, 0])] + [0, 0, 5.0],
                frame="local",
            )
        )
        app.run_steps(1)
        np.testing.assert_array_equal(d.body.positions[pinned], d.body.rest[pinned])
        assert np.any(d.body.positions[~pinned] != d.body.rest[~pinned])
    finally:
        app.close()


def test_dirty_is_a_union_until_the_renderer_clears_it(tmp_path):
    app = build_app(make_pack(tmp_path, SHEET.format(material="medium")))
    try:
        _, d = body(app)
        app.events.emit(GrabRequest("body", [0], d.body.rest[0] + [0, 0, 2.0], frame="local"))
        app.run_steps(1)
        first = set(d.body.last_order.tolist())
        app.events.emit(GrabRequest("body", [120], d.body.rest[120] + [0, 0, 2.0], frame="local"))
        app.run_steps(1)
        second = set(d.body.last_order.tolist())
        assert sorted(d.body.dirty.tolist()) == sorted(first | second) and len(d.body.dirty) == len(
            set(d.body.dirty.tolist())
        )
        d.body.take_dirty()  # what the render system does when it uploads
        app.events.emit(GrabRequest("body", [0], d.body.rest[0] + [0, 0, 3.0], frame="local"))
        app.run_steps(1)
        assert sorted(d.body.dirty.tolist()) == sorted(set(d.body.last_order.tolist()))
    finally:
        app.close()


def test_held_elements_stay_put_until_released(tmp_path):
    app = build_app(make_pack(tmp_path, SHEET.format(material="medium")))
    try:
        _, d = body(app)
        app.events.emit(GrabRequest("body", [0], d.body.rest[0] + [0, 0, 1.0], frame="local"))
        app.run_steps(1)
        held_at = d.body.positions[0].copy()
        app.events.emit(GrabRequest("body", [1], d.body.rest[1] + [0, 0, 6.0], frame="local"))
        app.run_steps(1)
        np.testing.assert_array_equal(d.body.positions[0], held_at)
        assert sorted(d.body.held.tolist()) == [0, 1]
        app.events.emit(ReleaseRequest("body", [0]))
        app.events.emit(GrabRequest("body", [1], d.body.rest[1] + [0, 0, 9.0], frame="local"))
        app.run_steps(1)
        assert d.body.positions[0, 2] > held_at[2]
        assert d.body.held.tolist() == [1]
    finally:
        app.close()


def test_digest_follows_positions_not_render_bookkeeping(tmp_path):
    app = build_app(make_pack(tmp_path, SHEET.format(material="medium")))
    try:
        _, d = body(app)
        before = world_digest(app)
        d.body.mark_dirty(np.arange(5, dtype=np.int64))
        assert world_digest(app) == before
        d.body.positions[3, 2] += 1.0
        assert world_digest(app) != before
    finally:
        app.close()


def test_simulation_kind_volume_gets_a_default_deformable(tmp_path):
    app = build_app(
        make_pack(
            tmp_path,
            """
[entities.body.mesh]
mesh = "block"
material = "medium"
[entities.body.simulation]
kind = "volume"
""",
        )
    )
    try:
        _, d = body(app)
        from chainsim.components.resources import PackResource
        from chainsim.systems.engine import meshgen

        mesh = app.resource(PackResource).pack.mesh("block")
        assert d.source == "volume"
        assert d.body.graph.n_links == len(meshgen.links_from_cells(mesh.tets))
        assert "deformation" in app.systems("simulation")
    finally:
        app.close()


def test_scripted_pull_reaches_its_target(tmp_path):
    app = build_app(
        make_pack(
            tmp_path,
            SHEET.format(material="medium")
            + """
fixed_boundary = true
[entities.body.pull]
at = [0.0, 0.0, 0.0]
path = [0.0, 0.0, 3.0, 1.0, 0.0, 3.0]
speed = 40.0
start = 0.05
""",
        )
    )
    try:
        ent, d = body(app)
        with app.active():
            p = esper.component_for_entity(ent, Pull)
        assert p.resolved == int(np.argmin(np.linalg.norm(d.body.rest, axis=1)))
        app.run_steps(60)
        assert p.done
        np.testing.assert_allclose(d.body.positions[p.resolved], [1.0, 0.0, 3.0], atol=1e-12)
        rim = d.body.fixed
        assert rim.sum() == 40  # the rim of an 11 x 11 sheet
        np.testing.assert_array_equal(d.body.positions[rim], d.body.rest[rim])
    finally:
        app.close()


@pytest.mark.parametrize(
    "table, needle",
    [
        ('[entities.body.mesh]\nmesh = "sheet"\n[entities.body.deformable]\nalpha_min = 1.5\n', "alpha_min"),
        ('[entities.body.mesh]\nmesh = "sheet"\n[entities.body.deformable]\nalpha_max = 0.5\n', "alpha_max"),
        ('[entities.body.mesh]\nmesh = "sheet"\n[entities.body.deformable]\nsource = "volume"\n', "tetrahedra"),
        ('[entities.body.mesh]\nmesh = "sheet"\n[entities.body.deformable]\nmaterial = "jelly"\n', "jelly"),
        ('[entities.body.mesh]\nmesh = "sheet"\n[entities.body.deformable]\nfixed = [5000]\n', "fixed"),
        ("[entities.body.deformable]\n", "mesh"),
        (
            '[entities.body.mesh]\nmesh = "sheet"\n[entities.body.deformable]\n[entities.body.pull]\npath = [1.0, '
            "2.0]\n",
            "path",
        ),
    ],
)
def test_bad_tables_are_one_line_user_errors(tmp_path, table, needle):
    with pytest.raises(UserError) as err:
        build_app(make_pack(tmp_path, table)).close()
    assert needle in str(err.value) and "\n" not in str(err.value)


def test_mouse_drag_pulls_the_nearest_element_and_releases_it(tmp_path):
    from chainsim.components.view_events import Dragged

    app = build_app(
        make_pack(
            tmp_path,
            SHEET.format(material="medium")
            + """
drag = true
[entities.body.transform]
position = [0.0, 0.0, 50.0]
""",
        )
    )
    try:
        ent, d = body(app)
        grab_world = d.body.rest[60] + [0.1, 0.0, 50.0]
        app.events.emit(Dragged("front", ent, "body", "start", 0, tuple(grab_world), tuple(grab_world)))
        app.events.emit(Dragged("front", ent, "body", "move", 0, tuple(grab_world), tuple(grab_world + [0, 0, 4.0])))
        app.run_steps(1)
        np.testing.assert_allclose(d.body.positions[60], d.body.rest[60] + [0, 0, 4.0])
        assert d.body.held.tolist() == [60]
        app.events.emit(Dragged("front", ent, "body", "end", 0, tuple(grab_world), tuple(grab_world + [0, 0, 5.0])))
        app.run_steps(1)
        np.testing.assert_allclose(d.body.positions[60], d.body.rest[60] + [0, 0, 5.0])
        assert len(d.body.held) == 0
    finally:
        app.close()


def test_mouse_drags_are_ignored_unless_the_body_asks_for_them(tmp_path):
    from chainsim.components.view_events import Dragged

    app = build_app(make_pack(tmp_path, SHEET.format(material="medium")))
    try:
        ent, d = body(app)
        p = tuple(d.body.rest[60])
        app.events.emit(Dragged("front", ent, "body", "start", 0, p, p))
        app.events.emit(Dragged("front", ent, "body", "move", 0, p, tuple(d.body.rest[60] + [0, 0, 4.0])))
        app.run_steps(1)
        np.testing.assert_array_equal(d.body.positions, d.body.rest)
    finally:
        app.close()


def test_cut_kills_crossed_links_and_the_pieces_move_apart(tmp_path):
    from chainsim.systems.tissue.events import CutRequest

    app = build_app(make_pack(tmp_path, SHEET.format(material="rigid")))
    try:
        ent, d = body(app)
        seen = app.events.reader(Deformed)
        # a blade across the whole sheet at x = 0.5 (between grid columns), pressed along z
        app.events.emit(
            CutRequest("body", p0=[0.5, -20.0, 0.0], p1=[0.5, 20.0, 0.0], normal=[0.0, 0.0, 1.0], frame="local")
        )
        app.run_steps(1)
        cut = [e for e in seen.read() if e.cut_count]
        assert cut and cut[0].cut_count == int((~d.body.alive).sum()) > 0
        a, b = (
            d.body.rest[d.body.graph.links[~d.body.alive, 0], 0],
            d.body.rest[d.body.graph.links[~d.body.alive, 1], 0],
        )
        assert np.all(np.minimum(a, b) < 0.5) and np.all(np.maximum(a, b) > 0.5)
        left = int(np.argmin(d.body.rest[:, 0]))
        app.events.emit(GrabRequest("body", [left], d.body.rest[left] + [0, 0, 3.0], frame="local"))
        app.run_steps(1)
        right_side = d.body.rest[:, 0] > 0.5
        np.testing.assert_array_equal(
            d.body.positions[right_side], d.body.rest[right_side]
        )  # no link left to pull them
        assert np.all(d.body.positions[~right_side, 2] == 3.0)
    finally:
        app.close()


def test_added_links_join_pieces_with_the_body_material(tmp_path):
    from chainsim.systems.tissue.events import AddLinksRequest, CutRequest

    app = build_app(make_pack(tmp_path, SHEET.format(material="rigid")))
    try:
        ent, d = body(app)
        app.events.emit(
            CutRequest("body", p0=[0.5, -20.0, 0.0], p1=[0.5, 20.0, 0.0], normal=[0.0, 0.0, 1.0], frame="local")
        )
        app.run_steps(1)
        m = d.body.graph.n_links
        a = int(np.argmin(np.abs(d.body.rest[:, 0] - 0.0) + np.abs(d.body.rest[:, 1])))
        b = int(np.argmin(np.abs(d.body.rest[:, 0] - 1.0) + np.abs(d.body.rest[:, 1])))
        app.events.emit(AddLinksRequest("body", [[a, b]]))
        app.run_steps(1)
        assert (
            d.body.graph.n_links == m + 1
            and len(d.body.limits[0]) == m + 1
            and d.body.limits[0][-1] == 1.0
            and d.body.limits[1][-1] == 1.0
        )
        left = int(np.argmin(d.body.rest[:, 0]))
        app.events.emit(GrabRequest("body", [left], d.body.rest[left] + [0, 0, 3.0], frame="local"))
        app.run_steps(1)
        np.testing.assert_allclose(d.body.positions[:, 2], 3.0)  # the stitch carries the pull across the cut
    finally:
        app.close()


@pytest.mark.parametrize("extra", ['order = "balanced"', 'order = "schill"', 'dtype = "float32"'])
def test_orders_and_single_precision_keep_the_grab_and_the_limits(tmp_path, extra):
    app = build_app(make_pack(tmp_path, SHEET.format(material="medium") + extra + "\n"))
    try:
        _, d = body(app)
        target = d.body.rest[60].astype(np.float64) + [2.0, 1.0, 4.0]
        app.events.emit(GrabRequest("body", [60], target, frame="local"))
        app.run_steps(1)
        assert d.body.positions.dtype == (np.float32 if "float32" in extra else np.float64)
        np.testing.assert_allclose(d.body.positions[60], target, rtol=1e-6)
        tol = 1e-5 if "float32" in extra else 1e-9
        rest, pos = d.body.rest.astype(np.float64), d.body.positions.astype(np.float64)
        for e, s in zip(d.body.last_order[1:], d.body.last_sponsor[1:]):
            lo, hi = _box(rest, pos, e, s, 0.8, 1.2, 0.1)
            assert np.all(pos[e] >= lo - tol) and np.all(pos[e] <= hi + tol)
        assert len(d.body.last_order) > 1
    finally:
        app.close()


def test_exact_material_keeps_every_link_inside_while_dragging(tmp_path):
    """`exact = true` in a material: after each grab of a drag (relaxation included), no link of the body is
    outside its limits, held and fixed elements stay, and the pass's moves reach the renderer as dirty ids."""
    from chainsim.systems.engine.kernels.exact import violations

    pack = make_pack(
        tmp_path,
        """
[materials.exact]
alpha_min = 0.8
alpha_max = 1.2
beta = 0.1
relax = 2
exact = true
"""
        + SHEET.format(material="exact")
        + """
fixed_box = [-100.0, -100.0, -1.0, -4.0, 100.0, 1.0]
order = "fifo"
""",
    )
    app = build_app(pack)
    try:
        _, d = body(app)
        assert d.body.exact and d.order == "breadth-first"
        app.events.emit(GrabRequest("body", [0], d.body.rest[0] + [0, 0, 1.5], frame="local"))  # held by a tool
        app.run_steps(1)
        held = d.body.positions[0].copy()
        g = int(np.argmax(d.body.rest[:, 0]))
        for k in range(1, 8):
            d.body.take_dirty()
            before = d.body.positions.copy()
            app.events.emit(GrabRequest("body", [g], d.body.rest[g] + [0.0, 1.5 * k, 2.5 * k], frame="local"))
            app.run_steps(1)
            v = violations(
                d.body.rest, d.body.positions, d.body.graph, d.body.limits[0], d.body.limits[1], d.body.limits[2]
            )
            assert v.outside == 0 and v.worst <= 1e-6, (k, v)
            np.testing.assert_array_equal(d.body.positions[d.body.fixed], d.body.rest[d.body.fixed])
            np.testing.assert_array_equal(d.body.positions[0], held)
            changed = np.flatnonzero(np.any(d.body.positions != before, axis=1))
            assert set(changed.tolist()) <= set(d.body.dirty.tolist())  # (none once the pull is past reach)
        assert d.body.last_shortfall > 0  # the last pulls go further than the limits allow from the fixed edge
    finally:
        app.close()

"""Ray picking and surface snapping (game/picking.py) and the Picked events of systems/view/cameras.py."""

import esper
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.components.core import Transform
from chainsim.components.input_events import MouseButton, MouseDrag, PickPoint
from chainsim.components.resources import EntityIndex, PendingInput
from chainsim.components.view_events import Picked
from chainsim.game.trainer.headless import build_app
from chainsim.systems.engine.raycast import closest_on_mesh, ray_mesh, ray_triangles, triangle_links
from chainsim.systems.view.cameras import ViewState
from chainsim.systems.view.picking import pick


def _reference_hit(o, d, a, b, c):
    """Plain barycentric solve of o + t d = a + u (b - a) + v (c - a)."""
    m = np.column_stack([-d, b - a, c - a])
    if abs(np.linalg.det(m)) < 1e-12:
        return np.inf
    t, u, v = np.linalg.solve(m, o - a)
    return t if (u >= 0 and v >= 0 and u + v <= 1 and t > 0) else np.inf


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000))
def test_ray_triangles_matches_a_direct_solve(seed):
    rng = np.random.default_rng(seed)
    tris = rng.uniform(-10, 10, (30, 3, 3))
    o = rng.uniform(-20, 20, 3)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    got = ray_triangles(o, d, tris[:, 0], tris[:, 1], tris[:, 2])
    want = np.array([_reference_hit(o, d, *t) for t in tris])
    finite = np.isfinite(want)
    # points within a hair of an edge may go either way; elsewhere the two must agree
    assert np.array_equal(np.isfinite(got), finite) or np.sum(np.isfinite(got) != finite) <= 1
    both = finite & np.isfinite(got)
    np.testing.assert_allclose(got[both], want[both], rtol=1e-7, atol=1e-7)


def test_ray_mesh_returns_the_nearest_of_stacked_triangles():
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 5], [1, 0, 5], [0, 1, 5]], float)
    tris = np.array([[0, 1, 2], [3, 4, 5]])
    assert ray_mesh([0.2, 0.2, 10.0], [0, 0, -1.0], verts, tris) == (1, 5.0)
    assert ray_mesh([0.2, 0.2, -1.0], [0, 0, 1.0], verts, tris) == (0, 1.0)
    assert ray_mesh([2.0, 2.0, 10.0], [0, 0, -1.0], verts, tris) is None


def test_closest_on_mesh_snaps_to_the_plane():
    verts = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0]], float)
    tri, p = closest_on_mesh(verts, np.array([[0, 1, 2]]), [2.0, 3.0, 7.0])
    assert tri == 0
    np.testing.assert_allclose(p, [2.0, 3.0, 0.0])


def test_triangle_links_finds_each_edge():
    tris = np.array([[0, 1, 2], [2, 1, 3]])
    links = np.array([[1, 2], [0, 1], [2, 0], [3, 1]])
    tl = triangle_links(tris, links)
    assert tl.tolist() == [[1, 0, 2], [0, 3, -1]]


def _ball(app):
    with app.active():
        ent = app.resource(EntityIndex)["ball"]
        return ent, esper.component_for_entity(ent, Transform).position.copy()


def test_click_on_the_ball_emits_one_picked_event_on_its_surface():
    app = build_app("loop-demo")
    try:
        app.events.log = []
        ent, centre = _ball(app)
        vp = app.resource(ViewState).get("main")
        x, y, _ = vp.camera.project(centre, vp.rect)[0]
        app.resource(PendingInput).extend(
            [(0.0, MouseButton(int(x), int(y), "left", True)), (0.0, MouseButton(int(x), int(y), "left", False))]
        )
        app.update(0.0)  # zero-length frame: the ball has not moved yet
        picks = [e for e in app.events.log if isinstance(e, Picked)]
        assert len(picks) == 1
        assert picks[0].entity == ent and picks[0].entity_name == "ball" and picks[0].viewport == "main"
        r = np.linalg.norm(np.array(picks[0].point) - centre)
        assert 14.0 < r < 15.0 + 1e-6  # on the tessellated sphere of radius 15
    finally:
        app.close()


def test_drag_is_not_a_pick():
    app = build_app("loop-demo")
    try:
        app.events.log = []
        _, centre = _ball(app)
        vp = app.resource(ViewState).get("main")
        x, y, _ = vp.camera.project(centre, vp.rect)[0]
        app.resource(PendingInput).extend(
            [
                (0.0, MouseButton(x, y, "left", True)),
                (0.0, MouseDrag(x + 30, y, 30, 0, "left")),
                (0.0, MouseButton(x, y, "left", False)),
            ]
        )
        app.update(0.0)
        assert [e for e in app.events.log if isinstance(e, Picked)] == []
    finally:
        app.close()


def test_scripted_pick_point_snaps_to_the_surface():
    app = build_app("loop-demo")
    try:
        app.events.log = []
        ent, centre = _ball(app)
        app.resource(PendingInput).extend([(0.0, PickPoint("ball", tuple(centre + [0.0, 0.0, 40.0])))])
        app.update(0.0)
        picks = [e for e in app.events.log if isinstance(e, Picked)]
        assert len(picks) == 1 and picks[0].entity == ent and picks[0].viewport == ""
        p = np.array(picks[0].point)
        assert abs(p[0] - centre[0]) < 1.0 and abs(p[1] - centre[1]) < 1.0
        assert 14.0 < p[2] - centre[2] <= 15.0 + 1e-6
    finally:
        app.close()


FIXED_PACK = """
[pack]
name = "fixedview"
format = 1

[settings]
window_size = [400.0, 300.0]

[meshes.box]
primitive = "box"
extents = [60.0, 60.0, 60.0]

[entities.box.mesh]
mesh = "box"
[entities.probe.transform]
position = [0.0, -150.0, 0.0]
rotation = [0.70710678, -0.70710678, 0.0, 0.0]

[layouts.two]
[[layouts.two.viewports]]
name = "controller"
kind = "fixed"
rect = [0.0, 0.0, 0.5, 1.0]
distance = 300.0
[[layouts.two.viewports]]
name = "tip"
kind = "attached"
attach = "probe"
rect = [0.5, 0.0, 0.5, 1.0]
"""


def _pack(tmp_path):
    root = tmp_path / "fixedview"
    root.mkdir()
    (root / "pack.toml").write_text(FIXED_PACK, encoding="utf-8")
    return str(root)


def test_drag_on_a_fixed_view_grabs_the_surface_and_follows_the_cursor(tmp_path):
    from chainsim.components.view_events import Dragged

    app = build_app(_pack(tmp_path))
    try:
        app.events.log = []
        vp = app.resource(ViewState).get("controller")
        x, y, _ = vp.camera.project([0.0, 0.0, 0.0], vp.rect)[0]
        x, y = int(x), int(y)
        app.resource(PendingInput).extend(
            [
                (0.0, MouseButton(x, y, "left", True)),
                (0.0, MouseDrag(x + 20, y + 10, 20, 10, "left")),
                (0.0, MouseButton(x + 20, y + 10, "left", False)),
            ]
        )
        app.update(0.0)
        drags = [e for e in app.events.log if isinstance(e, Dragged)]
        assert [d.phase for d in drags] == ["start", "move", "end"]
        assert drags[0].entity_name == "box"
        grab = np.array(drags[0].grab_point)
        assert abs(grab[1] - 30.0) < 1e-6  # the box face towards the camera (+Y side)
        moved = np.array(drags[1].point)
        assert abs(float((moved - grab) @ vp.camera.forward)) < 1e-6  # stays in the screen-parallel plane
        px, py, _ = vp.camera.project(moved, vp.rect)[0]
        assert abs(px - (x + 20.5)) < 1e-6 and abs(py - (y + 10.5)) < 1e-6
        assert vp.camera.yaw == 0.0  # a fixed camera does not turn
        assert len([e for e in app.events.log if isinstance(e, Picked)]) == 0  # a drag is not a click
    finally:
        app.close()


def test_attached_view_rides_on_its_entity_and_does_not_pick(tmp_path):
    from chainsim.systems.view.cameras import refresh_cameras

    app = build_app(_pack(tmp_path))
    try:
        app.events.log = []
        vs = app.resource(ViewState)
        with app.active():
            refresh_cameras(app, vs)
        tip = vs.get("tip")
        np.testing.assert_allclose(tip.camera.eye, [0.0, -150.0, 0.0], atol=1e-9)
        np.testing.assert_allclose(tip.camera.forward, [0.0, 1.0, 0.0], atol=1e-6)  # local +Z turned onto +Y
        cx, cy = tip.rect.x + tip.rect.w // 2, tip.rect.y + tip.rect.h // 2
        with app.active():
            o, d = tip.camera.ray(cx + 0.5, cy + 0.5, tip.rect)
            assert pick(app, o, d) is not None  # the box is right ahead of the probe ...
        app.resource(PendingInput).extend(
            [(0.0, MouseButton(cx, cy, "left", True)), (0.0, MouseButton(cx, cy, "left", False))]
        )
        app.update(0.0)
        assert [e for e in app.events.log if isinstance(e, Picked)] == []  # ... but the needle view only shows
    finally:
        app.close()

"""Camera math and layout rectangles (game/viewports.py): what the renderer and picking both rely on."""

import math

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from chainsim.systems.view.ui.viewports import OrbitCamera, Rect, attached_camera, fraction_rect, layout_rects


@settings(max_examples=50, deadline=None)
@given(st.integers(50, 3000), st.integers(50, 2000), st.floats(0.05, 0.95))
def test_side_by_side_viewports_tile_the_window(w, h, split):
    r = layout_rects(
        [{"name": "a", "rect": [0.0, 0.0, split, 1.0]}, {"name": "b", "rect": [split, 0.0, 1.0 - split, 1.0]}], w, h
    )
    assert r["a"].x == 0
    assert r["a"].x + r["a"].w == r["b"].x
    assert r["b"].x + r["b"].w == w
    assert r["a"].h == h and r["b"].h == h


def test_fraction_rect_is_bottom_left_origin():
    r = fraction_rect([0.5, 0.25, 0.5, 0.5], 800, 400)
    assert r == Rect(400, 100, 400, 200)
    assert r.contains(400, 100)
    assert not r.contains(800, 100)


def test_orbit_convention_yaw_zero_looks_along_minus_y():
    cam = OrbitCamera(target=np.array([1.0, 2.0, 3.0]), distance=100.0, yaw=0.0, pitch=0.0)
    np.testing.assert_allclose(cam.eye, [1.0, 102.0, 3.0], atol=1e-9)
    np.testing.assert_allclose(cam.forward, [0.0, -1.0, 0.0], atol=1e-12)
    cam.yaw, cam.pitch = 90.0, 0.0
    cam.update_eye()
    np.testing.assert_allclose(cam.eye, [-99.0, 2.0, 3.0], atol=1e-9)  # counter-clockwise from +Y is -X
    cam.pitch = 45.0
    cam.update_eye()
    assert cam.eye[2] > 3.0  # positive pitch lifts the eye


@settings(max_examples=40, deadline=None)
@given(st.floats(0, 360), st.floats(-80, 80), st.floats(50, 800), st.lists(st.floats(-40, 40), min_size=3, max_size=3))
def test_ray_through_projected_pixel_passes_through_point(yaw, pitch, dist, p):
    cam = OrbitCamera(target=np.zeros(3), distance=dist, yaw=yaw, pitch=pitch, near=1.0, far=5000.0)
    rect = Rect(37, 11, 640, 480)
    point = np.array(p)
    # a point nearer than the near plane (possible when the eye is within 70 mm of the target) is
    # clipped, not projected: only points the camera can see have a pixel to cast a ray through
    assume((point - cam.eye) @ cam.forward > 1.01 * cam.near)
    px, py, depth = cam.project(point, rect)[0]
    assert -1.0 < depth < 1.0
    o, d = cam.ray(px, py, rect)
    assert abs(np.linalg.norm(d) - 1.0) < 1e-9
    off = (point - o) - ((point - o) @ d) * d
    assert np.linalg.norm(off) < 1e-6 * dist


def test_target_projects_to_the_viewport_centre():
    cam = OrbitCamera(target=np.array([5.0, -3.0, 2.0]), distance=300, yaw=33, pitch=21)
    rect = Rect(100, 50, 400, 300)
    x, y, _ = cam.project(cam.target, rect)[0]
    assert abs(x - 300.0) < 1e-6 and abs(y - 200.0) < 1e-6


def test_vertical_field_of_view_matches_projection():
    cam = OrbitCamera(target=np.zeros(3), distance=100.0, yaw=0, pitch=0, fov=60.0)
    rect = Rect(0, 0, 200, 100)
    top = np.array([0.0, 0.0, 100.0 * math.tan(math.radians(30.0))])  # on the upper frustum edge at the target
    assert abs(cam.project(top, rect)[0][1] - 100.0) < 1e-6


def test_zoom_pan_rotate():
    rect = Rect(0, 0, 800, 600)
    cam = OrbitCamera(target=np.zeros(3), distance=400.0, yaw=10, pitch=20)
    cam.zoom(1.0)
    assert cam.distance < 400.0
    cam.zoom(-1.0)
    assert abs(cam.distance - 400.0) < 1e-9
    before = cam.project(np.zeros(3), rect)[0]
    cam.pan(30.0, -20.0, rect)
    after = cam.project(np.zeros(3), rect)[0]
    np.testing.assert_allclose(after[:2] - before[:2], [30.0, -20.0], atol=1e-6)  # the scene follows the cursor
    yaw = cam.yaw
    cam.rotate(10.0, 0.0)
    assert cam.yaw != yaw
    cam.rotate(0.0, -10000.0)
    assert cam.pitch <= 89.9


def test_attached_camera_looks_along_rotated_plus_z():
    # 90 degrees about +X maps local +Z to world -Y and local +Y to world +Z
    q = np.array([math.cos(math.pi / 4), math.sin(math.pi / 4), 0.0, 0.0])
    cam = attached_camera(
        position=[10.0, 20.0, 30.0], rotation=q, scale=2.0, offset=[0.0, 0.0, 5.0], fov=50, near=0.5, far=1000
    )
    np.testing.assert_allclose(cam.eye, [10.0, 10.0, 30.0], atol=1e-9)  # offset scaled and rotated
    np.testing.assert_allclose(cam.forward, [0.0, -1.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(cam.up, [0.0, 0.0, 1.0], atol=1e-9)
    ahead = cam.eye + 50.0 * cam.forward
    x, y, _ = cam.project(ahead, Rect(0, 0, 100, 100))[0]
    assert abs(x - 50.0) < 1e-6 and abs(y - 50.0) < 1e-6


def test_scaled_rect_for_hidpi():
    assert Rect(10, 20, 30, 40).scaled(2.0) == Rect(20, 40, 60, 80)


def test_a_scene_without_layout_gets_one_orbit_view_framing_every_mesh(tmp_path):
    import esper

    from chainsim.components.core import MeshRef, Transform
    from chainsim.components.resources import PackResource
    from chainsim.game.trainer.headless import build_app
    from chainsim.systems.view.cameras import ViewState

    root = tmp_path / "bare"
    root.mkdir()
    (root / "pack.toml").write_text(
        """
[pack]
name = "bare"
format = 1
[meshes.ball]
primitive = "sphere"
radius = 40.0
[entities.a.transform]
position = [500.0, 200.0, 30.0]
[entities.a.mesh]
mesh = "ball"
[entities.b.transform]
position = [650.0, 260.0, -20.0]
[entities.b.mesh]
mesh = "ball"
""",
        encoding="utf-8",
    )
    app = build_app(str(root))
    try:
        vs = app.resource(ViewState)
        assert [v.name for v in vs.viewports] == ["main"]
        vp = vs.viewports[0]
        assert vp.kind == "orbit" and vp.rect == Rect(0, 0, 1280, 800)
        pack = app.resource(PackResource).pack
        with app.active():
            for _, (ref, tr) in esper.get_components(MeshRef, Transform):
                pts = pack.mesh(ref.mesh).vertices + tr.position
                px = vp.camera.project(pts, vp.rect)
                assert np.all((px[:, 0] > 0) & (px[:, 0] < 1280) & (px[:, 1] > 0) & (px[:, 1] < 800))
                assert np.all(np.abs(px[:, 2]) < 1.0)
    finally:
        app.close()


# -- framing a box (fit_orbit) ----------------------------------------------------------------------


@settings(max_examples=150, deadline=None)
@given(
    centre=st.tuples(*[st.floats(-500, 500)] * 3),
    size=st.tuples(*[st.floats(20.0, 300)] * 3),  # boxes larger than the near plane allows for
    yaw=st.floats(0, 360),
    pitch=st.floats(-85, 85),
    rect=st.tuples(st.integers(0, 300), st.integers(0, 300), st.integers(120, 1600), st.integers(120, 1000)),
    top=st.sampled_from([0.0, 30.0, 92.0]),
)
def test_fit_orbit_puts_every_corner_inside_and_touches_an_edge(centre, size, yaw, pitch, rect, top):
    from chainsim.systems.view.ui.viewports import OrbitCamera, Rect, box_corners, fit_orbit

    lo = np.asarray(centre) - np.asarray(size) / 2
    hi = np.asarray(centre) + np.asarray(size) / 2
    r = Rect(*rect)
    cam = OrbitCamera(distance=50.0, yaw=yaw, pitch=pitch)
    fit_orbit(cam, r, lo, hi, margin=12.0, top=top)
    assert (cam.yaw, cam.pitch) == (yaw, pitch)  # the viewing direction is the layout's
    p = cam.project(box_corners(lo, hi), r)
    if r.h - 24.0 - top > 0.1 * r.h:  # room for the box under the top band
        y0, y1 = r.y + 12.0, r.y + r.h - 12.0 - top
    else:  # too short a view: the box is centred in the whole view, 5 % from its edges
        y0, y1 = r.y + 0.05 * r.h, r.y + 0.95 * r.h
    tol = 1e-3 * max(r.w, r.h)
    assert np.all(p[:, 1] >= y0 - tol) and np.all(p[:, 1] <= y1 + tol)
    assert np.all(p[:, 0] >= r.x + 12.0 - tol) and np.all(p[:, 0] <= r.x + r.w - 12.0 + tol)
    assert np.all(p[:, 2] > -1.0) and np.all(p[:, 2] < 1.0)  # in front of the eye, inside the clip range
    # as close as it can be: some corner sits on the left/right margins or on the band's top/bottom
    gaps = [p[:, 0].min() - r.x - 12.0, r.x + r.w - 12.0 - p[:, 0].max(), p[:, 1].min() - y0, y1 - p[:, 1].max()]
    assert min(gaps) < 0.01 * max(r.w, r.h)

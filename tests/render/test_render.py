"""Off-screen rendering (EGL): viewports, silhouettes, blending, picking agreement, deformation uploads."""

import numpy as np
import pytest
from conftest import frame_pixels, open_app

from chainsim.components.input_events import MouseButton
from chainsim.components.resources import PendingInput
from chainsim.components.view_events import Picked
from chainsim.systems.view.picking import pick

THREE_VIEWS = """
[layouts.three]
[[layouts.three.viewports]]
name = "left"
kind = "orbit"
rect = [0.0, 0.0, 0.6, 1.0]
[[layouts.three.viewports]]
name = "top"
kind = "fixed"
rect = [0.6, 0.55, 0.4, 0.45]
[[layouts.three.viewports]]
name = "panel"
kind = "panel"
rect = [0.6, 0.0, 0.4, 0.55]

[scenes.main]
layout = "three"
"""


def test_viewport_rectangles_are_where_the_layout_says(make_pack):
    app = open_app(make_pack(THREE_VIEWS), size=(333, 211))
    try:
        from chainsim.game.render.render_system import RenderTarget, collect_frame
        from chainsim.game.render.renderer import Renderer

        colours = {"left": (1.0, 0.0, 0.0, 1.0), "top": (0.0, 1.0, 0.0, 1.0), "panel": (0.0, 0.0, 1.0, 1.0)}
        with app.active():
            frame = collect_frame(app)
        frame.panels, frame.hud = [], None
        for v in frame.views:
            v.clear, v.title = colours[v.name], ""
        target = app.resource(RenderTarget)
        app.resource(Renderer).render(frame, target.fbo)
        img = np.frombuffer(target.fbo.read(components=3, alignment=1), np.uint8).reshape(211, 333, 3)
        want = np.zeros_like(img)
        # the layout fractions by hand: x split at round(0.6 * 333) = 200, y split at round(0.55 * 211) = 116
        want[:, :200] = (255, 0, 0)
        want[116:, 200:] = (0, 255, 0)
        want[:116, 200:] = (0, 0, 255)
        assert img.shape == (211, 333, 3)
        assert np.array_equal(img, want)
    finally:
        app.close()


BOX = """
[meshes.box]
primitive = "box"
extents = [40.0, 30.0, 20.0]

[materials.white]
color = [1.0, 1.0, 1.0, 1.0]
shading = "unlit"

[entities.box.transform]
position = [10.0, -5.0, 8.0]
rotation = [0.9238795, 0.0, 0.0, 0.3826834]
[entities.box.mesh]
mesh = "box"
material = "white"

[layouts.one]
[[layouts.one.viewports]]
name = "main"
kind = "orbit"
rect = [0.0, 0.0, 1.0, 1.0]
distance = 200.0
yaw = 25.0
pitch = 35.0
fov = 45.0
"""


def test_silhouette_lands_where_the_camera_math_projects_it(make_pack):
    from matplotlib.path import Path as MPath
    from scipy.spatial import ConvexHull

    from chainsim.systems.view.cameras import ViewState

    app = open_app(make_pack(BOX), size=(320, 240))
    try:
        _, img = frame_pixels(app)
        mask = img[:, :, 0] > 127
        vp = app.resource(ViewState).get("main")
        corners = np.array([[x, y, z] for x in (-20, 20) for y in (-15, 15) for z in (-10, 10)], float)
        import esper

        from chainsim.components.core import Transform

        with app.active():
            tr = esper.get_component(Transform)[0][1]
        world = corners @ tr.matrix()[:3, :3].T + tr.position
        px = vp.camera.project(world, vp.rect)[:, :2]
        hull = MPath(px[ConvexHull(px).vertices])
        ys, xs = np.mgrid[0:240, 0:320]
        centres = np.c_[xs.ravel() + 0.5, ys.ravel() + 0.5]
        inside = hull.contains_points(centres, radius=-1.5).reshape(240, 320)  # shrunk by 0.75 px
        outside = ~hull.contains_points(centres, radius=1.5).reshape(240, 320)  # grown by 0.75 px
        assert inside.sum() > 2000  # the box covers a good part of the view
        assert np.all(mask[inside])
        assert not np.any(mask[outside])
    finally:
        app.close()


SHEETS = """
[meshes.sheet]
primitive = "grid"
extents = [400.0, 400.0, 0.0]
resolution = [2.0, 2.0, 1.0]

[materials.red_half]
color = [1.0, 0.0, 0.0, 1.0]
opacity = 0.5
shading = "unlit"
[materials.green_half]
color = [0.0, 1.0, 0.0, 0.5]
shading = "unlit"
[materials.blue]
color = [0.0, 0.0, 1.0, 1.0]
shading = "unlit"

# listed nearest first: the renderer must still draw opaque first and see-through back to front
[entities.near.transform]
position = [0.0, 0.0, 30.0]
[entities.near.mesh]
mesh = "sheet"
material = "red_half"
[entities.mid.transform]
position = [0.0, 0.0, 0.0]
[entities.mid.mesh]
mesh = "sheet"
material = "green_half"
[entities.far.transform]
position = [0.0, 0.0, -30.0]
[entities.far.mesh]
mesh = "sheet"
material = "blue"

[layouts.top]
[[layouts.top.viewports]]
name = "main"
kind = "fixed"
rect = [0.0, 0.0, 1.0, 1.0]
distance = 300.0
pitch = 89.0
fov = 30.0
"""


def test_transparent_layers_blend_back_to_front_over_opaque(make_pack):
    app = open_app(make_pack(SHEETS), size=(64, 48))
    try:
        _, img = frame_pixels(app)
        centre = img[24, 32, :3].astype(float)
        blue, green, red = np.array([0, 0, 255.0]), np.array([0, 255.0, 0]), np.array([255.0, 0, 0])
        want = 0.5 * red + 0.5 * (0.5 * green + 0.5 * blue)
        assert np.all(np.abs(centre - want) <= 2.0)
    finally:
        app.close()


XRAY = """
[meshes.sheet]
primitive = "grid"
extents = [400.0, 400.0, 0.0]
resolution = [2.0, 2.0, 1.0]

[materials.red]
color = [1.0, 0.0, 0.0, 1.0]
shading = "unlit"
[materials.blue]
color = [0.0, 0.0, 1.0, 1.0]
shading = "unlit"

[entities.skin.transform]
position = [0.0, 0.0, 30.0]
[entities.skin.mesh]
mesh = "sheet"
material = "blue"
layer = "skin"
[entities.bone.mesh]
mesh = "sheet"
material = "red"

[layouts.top]
[[layouts.top.viewports]]
name = "main"
kind = "fixed"
rect = [0.0, 0.0, 0.75, 1.0]
distance = 300.0
pitch = 89.0
fov = 30.0
[[layouts.top.viewports]]
name = "panel"
kind = "panel"
rect = [0.75, 0.0, 0.25, 1.0]
[[layouts.top.widgets]]
name = "xray"
kind = "toggle"
layer = "xray:skin"
value = false
"""


def test_xray_toggle_makes_a_layer_see_through(make_pack):
    from chainsim.components.input_events import Widget
    from chainsim.game.render.render_system import XRAY_OPACITY

    app = open_app(make_pack(XRAY), size=(64, 48))
    try:
        _, before = frame_pixels(app)
        app.resource(PendingInput).extend([(0.0, Widget("xray", True))])
        app.update(0.0)
        _, after = frame_pixels(app)
        assert tuple(before[24, 24, :3]) == (0, 0, 255)
        want = XRAY_OPACITY * np.array([0, 0, 255.0]) + (1 - XRAY_OPACITY) * np.array([255.0, 0, 0])
        assert np.all(np.abs(after[24, 24, :3] - want) <= 2.0)
    finally:
        app.close()


def test_cpu_pick_returns_the_triangle_the_renderer_shows(gl_ctx):
    from chainsim.game.render.render_system import RenderTarget
    from chainsim.game.render.renderer import Renderer
    from chainsim.systems.view.cameras import ViewState

    app = open_app("loop-demo", size=(480, 300))
    try:
        frame, _ = frame_pixels(app)
        ent, tri = app.resource(Renderer).id_image(frame, "main", app.resource(RenderTarget).fbo.size)
        vs = app.resource(ViewState)
        vp = vs.get("main")
        # interior pixels: the same triangle on the whole 3 x 3 neighbourhood (edges are a coin toss)
        same = np.ones_like(tri, bool)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                same &= np.roll(np.roll(tri, dy, 0), dx, 1) == tri
                same &= np.roll(np.roll(ent, dy, 0), dx, 1) == ent
        same[[0, -1], :] = False
        same[:, [0, -1]] = False
        ys, xs = np.nonzero(same[:, : vp.rect.w] & (ent[:, : vp.rect.w] >= 0))
        assert len(ys) > 500
        rng = np.random.default_rng(7)
        k = rng.choice(len(ys), 120, replace=False)
        with app.active():
            for y, x in zip(ys[k], xs[k]):
                o, d = vp.camera.ray(x + 0.5, y + 0.5, vp.rect)
                hit = pick(app, o, d)
                assert hit is not None
                assert (hit.entity, hit.triangle) == (int(ent[y, x]), int(tri[y, x]))
            by, bx = np.nonzero(same[:, : vp.rect.w] & (ent[:, : vp.rect.w] < 0))
            for j in rng.choice(len(by), 40, replace=False):
                o, d = vp.camera.ray(bx[j] + 0.5, by[j] + 0.5, vp.rect)
                assert pick(app, o, d) is None
        # and through the whole input path: a click on a shown triangle emits Picked with it
        y, x = ys[k[0]], xs[k[0]]
        app.events.log = []
        app.resource(PendingInput).extend(
            [
                (0.0, MouseButton(float(x), float(y), "left", True)),
                (0.0, MouseButton(float(x), float(y), "left", False)),
            ]
        )
        app.update(0.0)
        picks = [e for e in app.events.log if isinstance(e, Picked)]
        assert [(p.entity, p.triangle) for p in picks] == [(int(ent[y, x]), int(tri[y, x]))]
    finally:
        app.close()


DEFORM = """
[meshes.sheet]
primitive = "grid"
extents = [100.0, 100.0, 0.0]
resolution = [20.0, 20.0, 1.0]

[materials.skin]
color = [1.0, 1.0, 1.0, 1.0]
shading = "unlit"

[entities.sheet.mesh]
mesh = "sheet"
material = "skin"
[entities.sheet.simulation]
kind = "surface"
[entities.sheet.deformable]
fixed_boundary = true

[layouts.top]
[[layouts.top.viewports]]
name = "main"
kind = "fixed"
rect = [0.0, 0.0, 1.0, 1.0]
distance = 400.0
pitch = 89.0
fov = 40.0
"""


def test_deformed_vertices_are_uploaded_in_place_with_fresh_normals(make_pack):
    import esper

    from chainsim.game.render.meshbuf import vertex_normals
    from chainsim.game.render.renderer import Renderer
    from chainsim.systems.tissue.deformable import Deformable

    app = open_app(make_pack(DEFORM), size=(200, 200))
    try:
        frame_pixels(app)
        with app.active():
            ent, d = esper.get_component(Deformable)[0]
        gm = app.resource(Renderer).meshes[ent]
        full = gm.n * 24
        before = gm.bytes_written
        moved = np.array([220, 221, 241])  # a patch in the middle of the 21 x 21 sheet
        d.body.positions[moved] += [5.0, -3.0, 12.0]
        d.body.mark_dirty(moved)
        _, img = frame_pixels(app)
        assert len(d.body.dirty) == 0  # the renderer took them
        written = gm.bytes_written - before
        assert 0 < written < full / 4
        gpu_pos = np.frombuffer(gm.vbo_pos.read(), np.float32).reshape(-1, 3)
        gpu_nrm = np.frombuffer(gm.vbo_nrm.read(), np.float32).reshape(-1, 3)
        np.testing.assert_allclose(gpu_pos, d.body.positions, atol=1e-4)
        np.testing.assert_allclose(gpu_nrm, vertex_normals(d.body.positions.astype(np.float32), gm.tris), atol=1e-5)
        # a second change far away also lands, and nothing else is rewritten
        d.body.positions[[0, 1]] += 1.0
        d.body.mark_dirty(np.array([0, 1]))
        frame_pixels(app)
        np.testing.assert_allclose(
            np.frombuffer(gm.vbo_pos.read(), np.float32).reshape(-1, 3), d.body.positions, atol=1e-4
        )
    finally:
        app.close()


def test_cut_links_hide_their_triangles_in_drawing_and_picking(make_pack):
    import esper

    from chainsim.game.render.renderer import Renderer
    from chainsim.systems.tissue.deformable import Deformable
    from chainsim.systems.view.cameras import ViewState

    app = open_app(make_pack(DEFORM), size=(200, 200))
    try:
        _, whole = frame_pixels(app)
        with app.active():
            ent, d = esper.get_component(Deformable)[0]
        links = np.asarray(d.body.graph.links)
        centre = np.array([0.0, 0.0, 0.0])
        mid = 0.5 * (d.body.positions[links[:, 0]] + d.body.positions[links[:, 1]])
        near = np.linalg.norm(mid - centre, axis=1) < 12.0
        d.body.graph.cut(near)
        _, holed = frame_pixels(app)
        gm = app.resource(Renderer).meshes[ent]
        assert len(gm.tri_ids) < len(gm.tris)
        assert whole[100, 100, 0] == 255
        assert holed[100, 100, 0] == 0  # the hole shows the background
        vp = app.resource(ViewState).get("main")
        with app.active():
            o, d_ = vp.camera.ray(100.5, 100.5, vp.rect)
            assert pick(app, o, d_) is None
    finally:
        app.close()


def test_wireframe_material_draws_links_not_faces(make_pack):
    body = DEFORM.replace('shading = "unlit"', 'shading = "unlit"\nwireframe = true')
    app = open_app(make_pack(body), size=(200, 200))
    try:
        _, img = frame_pixels(app)
        lit = img[:, :, 0] > 0
        frac = lit[50:150, 50:150].mean()
        assert 0.05 < frac < 0.6  # lines over the sheet, background between them
    finally:
        app.close()


def test_partial_uploads_match_a_full_recompute_on_random_patches(gl_ctx):
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from chainsim.game.render.meshbuf import GpuMesh, runs, vertex_normals
    from chainsim.systems.engine.meshgen import triangulated_grid

    pos0, tris, _ = triangulated_grid(15, 12, 2.0, dim=3)
    pos0 = np.asarray(pos0, float)
    gm = GpuMesh(gl_ctx, pos0, tris)
    try:
        current = pos0.copy()

        @settings(max_examples=30, deadline=None)
        @given(st.integers(0, 2**31 - 1), st.integers(1, 40))
        def check(seed, k):
            rng = np.random.default_rng(seed)
            ids = rng.choice(len(current), k, replace=False)
            current[ids] += rng.normal(scale=1.5, size=(k, 3))
            gm.mark(ids)
            gm.upload(current)
            gpu_pos = np.frombuffer(gm.vbo_pos.read(), np.float32).reshape(-1, 3)
            gpu_nrm = np.frombuffer(gm.vbo_nrm.read(), np.float32).reshape(-1, 3)
            np.testing.assert_allclose(gpu_pos, current, atol=1e-4)
            np.testing.assert_allclose(gpu_nrm, vertex_normals(current.astype(np.float32), gm.tris), atol=2e-5)

        check()
    finally:
        gm.release()
    assert runs(np.array([1, 2, 3, 900, 901]), gap=256) == [(1, 4), (900, 902)]
    assert runs(np.array([5, 100]), gap=256) == [(5, 101)]


ATTACHED = """
[meshes.box]
primitive = "box"
extents = [60.0, 10.0, 60.0]
[meshes.shell]
primitive = "sphere"
radius = 10.0

[materials.red]
color = [1.0, 0.0, 0.0, 1.0]
shading = "unlit"
[materials.green]
color = [0.0, 1.0, 0.0, 1.0]
shading = "unlit"

[entities.target.mesh]
mesh = "box"
material = "red"
[entities.probe.transform]
position = [0.0, -150.0, 0.0]
rotation = [0.70710678, -0.70710678, 0.0, 0.0]
[entities.probe.mesh]
mesh = "shell"
material = "green"

[layouts.two]
[[layouts.two.viewports]]
name = "room"
kind = "fixed"
rect = [0.0, 0.0, 0.5, 1.0]
distance = 400.0
yaw = 90.0
[[layouts.two.viewports]]
name = "tip"
kind = "attached"
attach = "probe"
rect = [0.5, 0.0, 0.5, 1.0]
fov = 40.0
"""


def test_attached_view_looks_ahead_of_its_entity_without_drawing_it(make_pack):
    app = open_app(make_pack(ATTACHED), size=(200, 100))
    try:
        _, img = frame_pixels(app)
        assert tuple(img[50, 150, :3]) == (255, 0, 0)  # the target straight ahead of the probe's +Z
        tip = img[:, 100:, :3].reshape(-1, 3)
        assert not np.any(np.all(tip == (0, 255, 0), axis=1))  # its own shell is not in the way
        room = img[:, :100, :3].reshape(-1, 3)
        assert np.any(np.all(room == (0, 255, 0), axis=1))  # but the room view shows it
    finally:
        app.close()


def test_hidpi_target_draws_the_same_layout_at_twice_the_pixels(make_pack):
    from chainsim.game.render.render_system import RenderTarget, draw, read_pixels

    app = open_app(make_pack(ATTACHED), size=(200, 100))
    try:
        draw(app)
        one = read_pixels(app).astype(int)
        app.resource(RenderTarget).scale = 2.0
        draw(app)
        two = read_pixels(app).astype(int)
        assert one.shape == (100, 200, 4)
        assert two.shape == (200, 400, 4)
        # same picture: the 2x image sampled at the centres of the 1x pixels agrees almost everywhere
        diff = np.abs(two[1::2, 1::2, :3] - one[:, :, :3]).max(axis=2)
        assert (diff > 40).mean() < 0.05
    finally:
        app.close()


def test_wire_toggle_switches_a_layer_to_its_links(make_pack):
    from chainsim.components.input_events import Widget

    body = XRAY.replace('layer = "xray:skin"', 'layer = "wire:skin"').replace('name = "xray"', 'name = "wire"')
    app = open_app(make_pack(body), size=(64, 48))
    try:
        _, before = frame_pixels(app)
        app.resource(PendingInput).extend([(0.0, Widget("wire", True))])
        app.update(0.0)
        _, after = frame_pixels(app)
        assert tuple(before[24, 24, :3]) == (0, 0, 255)  # the blue skin sheet covers the red bone
        view = after[:, :48, :3].reshape(-1, 3)
        red = np.all(view == (255, 0, 0), axis=1).mean()
        blue = np.all(view == (0, 0, 255), axis=1).mean()
        assert red > 0.5  # now the bone shows between the skin's links
        assert blue > 0.0  # and the links are drawn
    finally:
        app.close()


PANEL = """
[layouts.ctl]
[[layouts.ctl.viewports]]
name = "scene"
kind = "orbit"
rect = [0.0, 0.0, 0.5, 1.0]
[[layouts.ctl.viewports]]
name = "controller"
kind = "panel"
rect = [0.5, 0.0, 0.5, 1.0]
title = "Controller"
[[layouts.ctl.widgets]]
name = "bone"
kind = "light"
label = "Bone contact"
[[layouts.ctl.widgets]]
name = "target"
kind = "light"
label = "Foramen ovale"
[[layouts.ctl.widgets]]
name = "skin"
kind = "toggle"
label = "Show skin"
value = true
"""


def test_indicator_lights_show_the_hud_state(make_pack):
    from chainsim.components.hud import HudState
    from chainsim.game.render.renderer import LIGHT_RGBA
    from chainsim.systems.view.cameras import ViewState

    app = open_app(make_pack(PANEL), size=(400, 300))
    try:
        hud = app.resource(HudState)
        placed = {p.spec["name"]: p for p in app.resource(ViewState).panels["controller"]}

        def disc(img, name):  # the light's disc sits 10 px in from the widget's left edge
            r = placed[name].rect
            return tuple(int(c) for c in img[r.y + r.h // 2, r.x + 10, :3])

        rgb = {k: tuple(round(c * 255) for c in v[:3]) for k, v in LIGHT_RGBA.items()}
        _, img = frame_pixels(app, strip_overlay=False)
        assert disc(img, "bone") == rgb["off"] and disc(img, "target") == rgb["off"]
        hud.set_light("bone", "red")
        hud.set_light("target", "green")
        _, img = frame_pixels(app, strip_overlay=False)
        assert disc(img, "bone") == rgb["red"]
        assert disc(img, "target") == rgb["green"]
        with pytest.raises(ValueError):
            hud.set_light("bone", "blue")
    finally:
        app.close()


PLANES = """
[meshes.ball]
primitive = "sphere"
radius = 20.0

[materials.white]
color = [1.0, 1.0, 1.0, 1.0]
shading = "unlit"

[entities.ball.mesh]
mesh = "ball"
material = "white"

[planes.axial]
point = [0.0, 0.0, 0.0]
normal = [0.0, 0.0, 1.0]

[layouts.l]
[[layouts.l.viewports]]
name = "main"
kind = "fixed"
rect = [0.0, 0.0, 0.75, 1.0]
distance = 300.0
pitch = 60.0
[[layouts.l.viewports]]
name = "panel"
kind = "panel"
rect = [0.75, 0.0, 0.25, 1.0]
[[layouts.l.widgets]]
name = "planes"
kind = "toggle"
layer = "planes"
value = false
"""


def test_reference_planes_appear_when_their_toggle_is_on(make_pack):
    from chainsim.components.input_events import Widget

    app = open_app(make_pack(PLANES), size=(160, 120))
    try:
        _, off = frame_pixels(app)
        app.resource(PendingInput).extend([(0.0, Widget("planes", True))])
        app.update(0.0)
        _, on = frame_pixels(app)
        view_off, view_on = off[:, :120, :3].astype(int), on[:, :120, :3].astype(int)
        tinted = np.abs(view_on - view_off).sum(axis=2) > 10
        # a small outlined patch around the plane's point, not a quad across the whole view
        assert 0.005 < tinted.mean() < 0.3
        ys, xs = np.nonzero(tinted)
        assert abs(xs.mean() - 60) < 6  # centred on the ball in x
        over_bg = tinted & (view_off.sum(axis=2) == 0)
        assert over_bg.sum() > 20
        reds = view_on[over_bg]
        assert np.all(reds[:, 0] > reds[:, 1])  # the first plane colour is a red tint
    finally:
        app.close()

"""What the prp window draws stays what it was after the speed-ups: cached views, occlusion culling
and the display copies of the skull and skin (docs/rendering.md, "Frame rate under software GL")."""

from __future__ import annotations

import numpy as np
import pytest

from tests.render.conftest import open_app

CAMERAS = [(35.0, 10.0, 420.0), (200.0, 20.0, 420.0), (90.0, -30.0, 300.0), (0.0, 0.0, 150.0), (0.0, -80.0, 300.0)]


@pytest.fixture(scope="module")
def prp_app():
    from chainsim.components.loader import PackResource
    from chainsim.components.resources import PendingInput
    from chainsim.game.render import render_system as render
    from chainsim.game.trainer.inputscript import load_script

    app = open_app("prp", size=(640, 400))
    pres = app.resource(PackResource)
    app.resource(PendingInput).extend(load_script(pres.pack.file("scripts/correct.toml")))
    app.run_steps(int(1.8 / app.time.dt))  # landmarks placed and labelled, needle at the skin
    app.resource(render.RenderTarget).samples = 1  # exact comparisons
    yield app
    app.close()


def _pixels(app) -> np.ndarray:
    from chainsim.game.render import render_system as render

    render.draw(app)
    return render.read_pixels(app).astype(np.int16)


def _camera(app, yaw, pitch, distance):
    from chainsim.systems.view.cameras import ViewState

    cam = app.resource(ViewState).get("surgeon").camera
    cam.yaw, cam.pitch, cam.distance = yaw, pitch, distance
    cam.update_eye()


@pytest.mark.parametrize("yaw,pitch,distance", CAMERAS)
def test_culling_enclosed_meshes_never_hides_what_shows(prp_app, yaw, pitch, distance):
    from chainsim.game.render.renderer import Renderer

    r = prp_app.resource(Renderer)
    _camera(prp_app, yaw, pitch, distance)
    try:
        r.cull_enclosed = False
        everything = _pixels(prp_app)
        r.cull_enclosed = True
        culled = _pixels(prp_app)
    finally:
        r.cull_enclosed = True
    assert np.array_equal(everything, culled)


@pytest.mark.parametrize("yaw,pitch,distance", CAMERAS)
def test_back_faces_skipped_only_where_they_cannot_show(prp_app, yaw, pitch, distance):
    from chainsim.game.render.renderer import Renderer

    r = prp_app.resource(Renderer)
    _camera(prp_app, yaw, pitch, distance)
    try:
        r.cull_back = False
        both = _pixels(prp_app)
        r.cull_back = True
        front = _pixels(prp_app)
    finally:
        r.cull_back = True
    diff = np.abs(both - front).max(axis=-1)
    # a few silhouette pixels may differ: where the rasteriser leaves a crack between two front
    # faces at the very edge, the back face behind it no longer fills the crack
    assert np.count_nonzero(diff) <= 20


@pytest.mark.parametrize("yaw,pitch,distance", CAMERAS)
def test_big_meshes_drawn_nearest_first_look_the_same(prp_app, monkeypatch, yaw, pitch, distance):
    """The skull (opaque, open, 16k triangles) is drawn in the stored order nearest the eye's
    direction; with the skin see-through it shows, and the picture is the one drawn in file order."""
    from chainsim.components.input_events import Widget
    from chainsim.components.resources import PendingInput
    from chainsim.game.render import meshbuf

    _camera(prp_app, yaw, pitch, distance)
    pending = prp_app.resource(PendingInput)
    del pending.items[pending.cursor :]
    pending.push(prp_app.time.sim_time, Widget("skin_transparent", True))
    prp_app.update(prp_app.time.dt)
    try:
        ordered = _pixels(prp_app)
        monkeypatch.setattr(meshbuf, "SORTED_MIN", 10**9)
        plain = _pixels(prp_app)
    finally:
        pending.push(prp_app.time.sim_time, Widget("skin_transparent", False))
        prp_app.update(prp_app.time.dt)
    diff = np.abs(ordered - plain).max(axis=-1)
    # only where two triangles meet at equal depth can the order decide which shows
    assert np.count_nonzero(diff > 2) <= 10


@pytest.mark.parametrize("see_through", [False, True])
def test_landmark_labels_show_where_their_point_can_be_seen(see_through):
    """From all round the head, skin opaque or see-through (then the skull and jaw hide what is
    behind them), a landmark's label is drawn where a ray from the eye
    reaches its point and not where the head stands between: checked against ray casts through
    the opaque anatomy as drawn; points that lie within a couple of millimetres of showing (seen at
    a grazing angle or past an edge) are left out, as the label's probe is a 1.2 mm ball."""
    import trimesh

    from chainsim.components.input_events import Widget
    from chainsim.components.loader import PackResource
    from chainsim.components.resources import PendingInput
    from chainsim.game.render import render_system as render
    from chainsim.game.render.renderer import Renderer
    from chainsim.game.trainer.inputscript import load_script
    from chainsim.systems.view.cameras import ViewState

    app = open_app("prp", size=(640, 400))
    try:
        pres = app.resource(PackResource)
        app.resource(PendingInput).extend(load_script(pres.pack.file("scripts/correct.toml")))
        app.run_steps(int(1.8 / app.time.dt))
        pending = app.resource(PendingInput)
        del pending.items[pending.cursor :]
        pending.push(app.time.sim_time, Widget("skin_transparent", see_through))
        app.update(app.time.dt)
        r = app.resource(Renderer)
        frame = render.draw(app)
        parts = []
        for m in frame.meshes:
            hidden_inside = m.inside is not None and m.inside.color[3] >= 0.999
            if m.color[3] < 0.999 or m.wireframe or hidden_inside or len(m.gpu.tri_ids) < 1000:
                # see-through; enclosed by the opaque skin (nothing it hides is not hidden already); or
                # an instrument: the needle runs through landmark 1 and hides only a sliver of its probe
                continue
            model = np.asarray(m.model, float)
            v = m.gpu.pos.astype(float) @ model[:3, :3].T + model[:3, 3]
            parts.append(trimesh.Trimesh(v, m.gpu.tris[m.gpu.tri_ids], process=False))
        scene = trimesh.util.concatenate(parts)
        rays = trimesh.ray.ray_triangle.RayMeshIntersector(scene)
        view = app.resource(ViewState).get("surgeon")
        checked = {True: 0, False: 0}

        def blocked(eye, target, margin):
            """Whether an opaque surface crosses the ray from `eye` more than `margin` mm before `target`."""
            d = target - eye
            dist = np.linalg.norm(d)
            hits, _, _ = rays.intersects_location([eye], [d / dist], multiple_hits=True)
            return bool(len(hits)) and np.linalg.norm(hits - eye, axis=1).min() < dist - margin

        for yaw in range(0, 360, 30):
            for pitch in (-40.0, 0.0, 40.0):
                _camera(app, float(yaw), pitch, 420.0)
                drawn = render.draw(app)
                rect = view.rect.scaled(frame.scale)
                seen = r._seen(r._labels_seen[(rect.x, rect.y, rect.w, rect.h)])
                eye = np.asarray(view.camera.eye, float)
                for k, (pos, _text, _c) in enumerate(drawn.labels):
                    pos = np.asarray(pos, float)
                    _, _, face = trimesh.proximity.closest_point(scene, [pos])
                    outward = pos + 2.0 * scene.face_normals[face[0]]  # past the probe ball (1.2 mm)
                    if not blocked(eye, pos, 0.3):
                        visible = True  # the point itself can be seen
                    elif blocked(eye, outward, 1.0):
                        visible = False  # not even the ball's outer side can
                    else:
                        continue
                    checked[visible] += 1
                    assert seen[k] == visible, f"label {k + 1} from yaw {yaw}, pitch {pitch}: drawn {seen[k]}"
        assert checked[True] >= 10 and checked[False] >= 10, checked
    finally:
        app.close()


def test_closed_outward_surfaces_are_told_apart():
    from chainsim.game.render.meshbuf import _closed_outward
    from chainsim.game.render.renderer import icosphere

    v, f = icosphere(1)
    assert _closed_outward(v, f)
    assert not _closed_outward(v, f[:, ::-1])  # wound inward
    assert not _closed_outward(v, f[1:])  # a hole
    # a crease: the first face gets its own copies of its corners - still closed
    split = np.vstack([v, v[f[0]]])
    g = f.copy()
    g[0] = [len(v), len(v) + 1, len(v) + 2]
    assert _closed_outward(split, g)


def test_cached_views_match_fresh_ones_and_redraw_on_change(prp_app):
    from chainsim.game.render.renderer import STILL_FRAMES, Renderer

    r = prp_app.resource(Renderer)
    try:
        for yaw, pitch, distance in CAMERAS[:3]:
            _camera(prp_app, yaw, pitch, distance)
            r.cache_views(False)
            fresh = _pixels(prp_app)
            r.cache_views(True)
            vc = r.view_cache
            first = _pixels(prp_app)  # new views: drawn straight into the frame
            assert vc.direct == 2 and vc.redrawn == 0
            for _ in range(STILL_FRAMES - 1):  # not yet still long enough: drawn straight again
                _pixels(prp_app)
            direct = vc.direct
            assert direct == 2 * STILL_FRAMES and vc.redrawn == 0
            imaged = _pixels(prp_app)  # still long enough: drawn into their images
            assert vc.redrawn == 2
            copied = _pixels(prp_app)  # unchanged: copied
            assert vc.redrawn == 2 and vc.reused == 2, "an unchanged frame redrew a view"
            assert np.array_equal(first, fresh)
            # llvmpipe rasterises in screen tiles, so a view drawn at its own origin may differ by one
            # level in a few blended pixels; nothing else differs
            for img in (imaged, copied):
                diff = np.abs(img - fresh).max(axis=-1)
                assert diff.max() <= 2 and np.count_nonzero(diff) < 200
            _camera(prp_app, yaw + 5.0, pitch, distance)
            _pixels(prp_app)
            assert vc.direct == direct + 1 and vc.reused == 3, "only the surgeon's view moved"
    finally:
        r.cache_views(False)


@pytest.mark.parametrize("see_through", [False, True])
@pytest.mark.parametrize("blit", [True, False])
def test_a_needle_turned_over_a_still_view_looks_as_drawn_afresh(prp_app, monkeypatch, see_through, blit):
    """Turning a dial moves only the needle in the surgeon's view: that view is its layer (the rest,
    drawn once, with its depth) plus the needle drawn over it each frame; with a see-through skin the
    needle's screen box is made again from the layer and the skin blended over it. Copies are
    blitted where the GL can, drawn otherwise. Either way every frame equals one drawn afresh."""
    from chainsim.components.input_events import Widget
    from chainsim.components.resources import PendingInput
    from chainsim.game.render import rawgl as blit_module
    from chainsim.game.render.renderer import Renderer

    if not blit:
        monkeypatch.setattr(blit_module, "_entry_points", lambda: None)
    app = prp_app
    r = app.resource(Renderer)
    _camera(app, 35.0, 10.0, 420.0)
    pending = app.resource(PendingInput)
    del pending.items[pending.cursor :]  # the rest of the script: the dials are this test's

    def set_widget(name, value):
        app.resource(PendingInput).push(app.time.sim_time, Widget(name, value))
        app.update(app.time.dt)

    try:
        set_widget("skin_transparent", see_through)
        r.cache_views(True)
        vc = r.view_cache
        for k, angle in enumerate([0.0, 4.0, 9.0, 9.0, 15.0, 22.0, 30.0, 30.0, 38.0]):
            set_widget("rotate_horizontal", angle)
            r.view_cache = None
            fresh = _pixels(app)
            r.view_cache = vc
            cached = _pixels(app)
            diff = np.abs(cached - fresh).max(axis=-1)
            # where the needle meets the skin or a landmark at equal depth, which shows is arbitrary in
            # any depth-buffered drawing (the one drawn first wins, and the layer is drawn first); the cheek's
            # tissue face, finer than the skin, meets the shaft along a few more pixels
            assert np.count_nonzero(diff > 2) <= 8 and np.count_nonzero(diff) < 200, f"frame {k}: pixels differ"
        assert vc.layered >= 6, "the needle was not drawn over the surgeon's view layer"
        # once when the needle first moved; the needle-tip view, whose camera rides on the needle, makes
        # a layer of its own when the needle pauses for a frame
        assert vc.views["surgeon"].layers == 1, "the layer was drawn again while only the needle moved"
        assert (vc.blits > 0) == (blit and blit_module._entry_points() is not None)
    finally:
        r.cache_views(False)
        set_widget("rotate_horizontal", 0.0)
        set_widget("skin_transparent", False)


def test_text_drawn_as_inked_boxes_looks_as_whole_cells(prp_app, monkeypatch):
    """Glyphs are drawn as their inked boxes, not whole atlas cells: the same pixels, plain and bold;
    slanted (italic on help pages), a pixel may take the neighbouring texel where its sample falls on
    a texel boundary, as the two quads interpolate the same texture coordinate in different steps."""
    from chainsim.game.render import render_system as render
    from chainsim.game.render.renderer import Renderer

    r = prp_app.resource(Renderer)
    ov = r.overlay
    text = "Insert the needle: |Dist1 - 25| <= 2.0 mm, gq@W_{}"
    big = ov.font_sized(22)

    def draw(slanted: bool):
        target = prp_app.resource(render.RenderTarget)
        target.fbo.use()
        target.fbo.clear(0.1, 0.2, 0.3, 1.0)
        ov._laid_out.clear()
        if slanted:
            ov.label(text, 10.0, 200.0, (0.9, 1, 1, 1), slant=0.25)
            ov.label(text, 10.0, 150.0, (1, 1, 1, 1), font=big, bold=True, slant=0.2)
        else:
            ov.label(text, 10.5, 300.0, (1, 1, 0.8, 1))
            ov.label(text, 10.0, 250.0, (1, 1, 1, 0.7), bold=True)
            ov.label(text, 10.0, 150.0, (1, 1, 1, 1), font=big)
        ov.flush(tuple(target.fbo.size))
        return render.read_pixels(prp_app).astype(np.int16)

    inked = [draw(False), draw(True)]
    for f in (ov.font, big):
        monkeypatch.setattr(f, "ink", {ch: (0, 0, f.cell_w, f.cell_h) for ch in f.ink})
    cells = [draw(False), draw(True)]
    ov._laid_out.clear()
    for img in cells:
        assert np.count_nonzero(np.abs(img - img[0, 0]).max(axis=-1)) > 2000  # text was drawn
    assert np.array_equal(cells[0], inked[0])
    text_px = np.count_nonzero(np.abs(cells[1] - cells[1][0, 0]).max(axis=-1))
    assert np.count_nonzero(np.abs(cells[1] - inked[1]).max(axis=-1)) < 0.1 * text_px


def test_display_copies_are_lighter_and_close_to_the_full_meshes():
    import trimesh

    from chainsim.game.packs.discovery import resolve
    from chainsim.game.packs.pack import load

    pack = load(resolve("prp")[0])
    full, light = pack.mesh("skull"), pack.display_mesh("skull")
    assert len(light.triangles) * 3 < len(full.triangles)
    surface = trimesh.Trimesh(full.vertices, full.triangles, process=False)
    _, dist, _ = trimesh.proximity.closest_point(surface, light.vertices[::20])
    assert dist.max() < 1.0  # mm
    skin, shown = pack.mesh("skin"), pack.display_mesh("skin")
    assert shown.vertices[:, 2].min() > skin.vertices[:, 2].min()  # the ragged neck rim is cut away
    face = skin.vertices[:, 2] > -60.0
    # what is drawn of the face: the display skin (the collision skin itself) and, over each cheek, the
    # tissue volume's skin face, whose nodes lie on the skin and whose 2 mm triangles cut its creases
    drawn = [trimesh.Trimesh(shown.vertices, shown.triangles, process=False)]
    for side in ("left", "right"):
        tissue = pack.mesh(f"tissue_{side}")
        drawn.append(trimesh.Trimesh(tissue.vertices, tissue.triangles, process=False))
    _, dist, _ = trimesh.proximity.closest_point(trimesh.util.concatenate(drawn), skin.vertices[face][::25])
    assert np.median(dist) < 1e-6 and dist.max() < 0.1


def test_bench_render_pack_writes_its_report(tmp_path):
    import json

    from chainsim.game.cli.main import main

    out = tmp_path / "bench"
    rc = main(
        ["bench", "render", "--pack", "prp", "--size", "320x200", "--frames", "1", "--warmup", "0", "--out", str(out)]
    )
    assert rc == 0
    info = json.loads((out / "results-pack.json").read_text())
    assert info["pack"] == "prp" and info["median_ms"]
    assert all(v > 0 for v in info["median_ms"].values())


def _winding(points: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Generalised winding number of a closed surface at each point (1 inside, 0 outside)."""
    tri = vertices[faces]
    out = []
    for chunk in np.array_split(points, max(1, len(points) // 64)):
        a = tri[None] - chunk[:, None, None, :]
        x, y, z = a[:, :, 0], a[:, :, 1], a[:, :, 2]
        lx, ly, lz = (np.linalg.norm(v, axis=-1) for v in (x, y, z))
        det = np.einsum("pfi,pfi->pf", x, np.cross(y, z))
        den = (
            lx * ly * lz
            + np.einsum("pfi,pfi->pf", x, y) * lz
            + np.einsum("pfi,pfi->pf", y, z) * lx
            + np.einsum("pfi,pfi->pf", z, x) * ly
        )
        out.append(np.arctan2(det, den).sum(axis=1) / (2.0 * np.pi))
    return np.concatenate(out)


def test_meshes_said_to_be_inside_the_skin_are_inside_it():
    """The pack's `inside = "skin"` lets the renderer skip the skull behind an opaque skin; that is
    only sound if every drawn vertex of it lies inside the drawn skin (sampled, winding numbers)."""
    from chainsim.game.packs.discovery import resolve
    from chainsim.game.packs.pack import load

    pack = load(resolve("prp")[0])
    skin = pack.display_mesh("skin")
    inner = [n for n, spec in pack.manifest["meshes"].items() if spec.get("inside") == "skin"]
    assert {"skull", "mandible"} <= set(inner)
    for name in inner:
        m = pack.display_mesh(name)
        pts = m.vertices[:: max(1, len(m.vertices) // 400)]
        w = _winding(pts, skin.vertices, skin.triangles)
        assert w.min() > 0.5, f"{name} reaches outside the skin"


def test_text_laid_out_once_draws_the_same_quads(gl_ctx):
    from chainsim.game.render.overlay import Overlay

    ov = Overlay(gl_ctx)
    try:
        first = ov.label("Horizontal turn (deg)", 10.5, 20.0, (1, 1, 1, 1), max_w=90.0)
        quads = list(ov.glyphs[ov.font])
        again = ov.label("Horizontal turn (deg)", 10.5, 20.0, (1, 1, 1, 1), max_w=90.0)
        assert again == first and ov.glyphs[ov.font][len(quads) :] == quads
        moved = ov.label("Horizontal turn (deg)", 11.5, 20.0, (1, 1, 1, 1), max_w=90.0)
        assert moved == first + 1.0
        assert ov.font.width("abc") == ov.font.width("abc") > 0
    finally:
        ov.release()

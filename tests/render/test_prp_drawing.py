"""What the prp window draws stays what it was after the speed-ups: cached views, occlusion culling
and the display copies of the skull and skin (docs/rendering.md, "Frame rate under software GL")."""

from __future__ import annotations

import numpy as np
import pytest

from tests.render.conftest import open_app

CAMERAS = [(35.0, 10.0, 420.0), (200.0, 20.0, 420.0), (90.0, -30.0, 300.0), (0.0, 0.0, 150.0), (0.0, -80.0, 300.0)]


@pytest.fixture(scope="module")
def prp_app():
    from chainsim.components.resources import PendingInput
    from chainsim.game.app.inputscript import load_script
    from chainsim.game.app.loader import PackResource
    from chainsim.game.gl import render_system as render

    app = open_app("prp", size=(640, 400))
    pres = app.resource(PackResource)
    app.resource(PendingInput).extend(load_script(pres.pack.file("scripts/correct.toml")))
    app.run_steps(int(1.8 / app.time.dt))  # landmarks placed and labelled, needle at the skin
    app.resource(render.RenderTarget).samples = 1  # exact comparisons
    yield app
    app.close()


def _pixels(app) -> np.ndarray:
    from chainsim.game.gl import render_system as render

    render.draw(app)
    return render.read_pixels(app).astype(np.int16)


def _camera(app, yaw, pitch, distance):
    from chainsim.systems.view import ViewState

    cam = app.resource(ViewState).get("surgeon").camera
    cam.yaw, cam.pitch, cam.distance = yaw, pitch, distance
    cam.update_eye()


@pytest.mark.parametrize("yaw,pitch,distance", CAMERAS)
def test_occlusion_culling_never_hides_what_shows(prp_app, yaw, pitch, distance):
    from chainsim.game.gl.renderer import Renderer

    r = prp_app.resource(Renderer)
    _camera(prp_app, yaw, pitch, distance)
    try:
        r.occlusion_culling = False
        everything = _pixels(prp_app)
        r.occlusion_culling = True
        culled = _pixels(prp_app)
    finally:
        r.occlusion_culling = True
    assert np.array_equal(everything, culled)


def test_cached_views_match_fresh_ones_and_redraw_on_change(prp_app):
    from chainsim.game.gl.renderer import Renderer

    r = prp_app.resource(Renderer)
    try:
        for yaw, pitch, distance in CAMERAS[:3]:
            _camera(prp_app, yaw, pitch, distance)
            r.cache_views(False)
            fresh = _pixels(prp_app)
            r.cache_views(True)
            drawn = _pixels(prp_app)
            before = r.view_cache.redrawn
            copied = _pixels(prp_app)
            assert r.view_cache.redrawn == before, "an unchanged frame redrew a view"
            # llvmpipe rasterises in screen tiles, so a view drawn at its own origin may differ by one
            # level in a few blended pixels; nothing else differs
            for img in (drawn, copied):
                diff = np.abs(img - fresh).max(axis=-1)
                assert diff.max() <= 2 and np.count_nonzero(diff) < 200
            _camera(prp_app, yaw + 5.0, pitch, distance)
            _pixels(prp_app)
            assert r.view_cache.redrawn == before + 1, "only the surgeon's view moved"
    finally:
        r.cache_views(False)


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
    _, dist, _ = trimesh.proximity.closest_point(
        trimesh.Trimesh(shown.vertices, shown.triangles, process=False), skin.vertices[face][::25]
    )
    assert dist.max() < 1e-6  # the face and head are the collision skin itself


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

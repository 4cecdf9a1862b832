"""The C-arm view off screen (EGL): attenuation through closed meshes, the shots of a correct attempt,
frozen images, and `chainsim snapshot prp --scene fluoro` (thesis 3.2.3)."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
from conftest import open_app
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

from chainsim.components.input_events import Widget
from chainsim.components.resources import Assessment, PendingInput
from chainsim.game.render.radiograph import grey
from chainsim.game.trainer.inputscript import load_script
from chainsim.systems.view.ui.viewports import Rect, carm_camera

ROOT = Path(__file__).resolve().parents[2]
PACK = ROOT / "assets" / "prp"


def _box_chord(origin, direction, lo, hi) -> float:
    """Length of the ray inside the axis-aligned box [lo, hi] (slab method), 0 when it misses."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (lo - origin) / direction
        t2 = (hi - origin) / direction
    tmin = np.nanmax(np.minimum(t1, t2))
    tmax = np.nanmin(np.maximum(t1, t2))
    return float(max(tmax - max(tmin, 0.0), 0.0))


box = st.tuples(
    st.tuples(*[st.floats(-40.0, 40.0)] * 3),  # centre, mm
    st.tuples(*[st.floats(4.0, 60.0)] * 3),  # extents, mm
    st.floats(0.005, 2.0),  # attenuation, 1/mm
)


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(boxes=st.lists(box, min_size=1, max_size=3), az=st.floats(0.0, 360.0), el=st.floats(-60.0, 60.0))
def test_attenuation_is_mu_times_the_chord_through_each_closed_mesh(gl_ctx, boxes, az, el):
    """Each pixel of the float image holds sum(mu * length of the pixel-centre ray inside each mesh),
    overlapping meshes included, checked against the slab chord of the same rays."""
    import trimesh

    from chainsim.game.render.meshbuf import GpuMesh
    from chainsim.game.render.radiograph import FluoroRenderer, XrayMesh

    fr = FluoroRenderer(gl_ctx, size=96)
    gms = []
    try:
        meshes = []
        for centre, ext, mu in boxes:
            b = trimesh.creation.box(extents=ext)
            b.apply_translation(centre)
            gm = GpuMesh(gl_ctx, b.vertices, b.faces)
            gms.append(gm)
            meshes.append(XrayMesh(gm, np.eye(4), mu))
        cam = carm_camera(az, el, (0.0, 0.0, 0.0), 600.0, 1000.0, 230.0)
        path = fr.capture(meshes, cam)
        rect = Rect(0, 0, 96, 96)
        rng = np.random.default_rng(0)
        checked = 0
        for _ in range(300):
            i, j = (int(v) for v in rng.integers(0, 96, 2))  # row (top first), column
            o, d = cam.ray(j + 0.5, 96 - i - 0.5, rect)
            want = 0.0
            near_edge = False
            for centre, ext, mu in boxes:
                lo = np.asarray(centre) - np.asarray(ext) / 2
                hi = np.asarray(centre) + np.asarray(ext) / 2
                want += mu * _box_chord(o, d, lo, hi)
                # a pixel whose neighbourhood straddles an edge can be covered either way: skip it
                # (every neighbour within 0.6 px: a silhouette edge may run along either diagonal)
                for di, dj in (
                    (-0.6, -0.6),
                    (0.6, 0.6),
                    (-0.6, 0.6),
                    (0.6, -0.6),
                    (0, 0.6),
                    (0, -0.6),
                    (0.6, 0),
                    (-0.6, 0),
                ):
                    o2, d2 = cam.ray(j + 0.5 + dj, 96 - i - 0.5 + di, rect)
                    if (_box_chord(o2, d2, lo, hi) > 0) != (_box_chord(o, d, lo, hi) > 0):
                        near_edge = True
            if near_edge:
                continue
            assert path[i, j] == pytest.approx(want, abs=2e-3 + 1e-4 * want)
            checked += 1
        assert checked > 100
    finally:
        for gm in gms:
            gm.release()
        fr.release()


def _play(app, events, seconds):
    app.resource(PendingInput).extend(sorted(events, key=lambda e: e[0]))
    for _ in range(int(seconds / app.time.dt)):
        app.update(app.time.dt)


def _correct_app():
    app = open_app(str(PACK))
    events = load_script(PACK / "scripts" / "correct.toml")
    return app, events, max(t for t, _ in events)


def _project(cam, points, n):
    xy = cam.project(np.asarray(points, float), Rect(0, 0, n, n))[:, :2]
    return np.c_[xy[:, 0], n - xy[:, 1]]  # (column, row from the top)


def test_submental_shot_of_a_correct_attempt_shows_the_needle_in_the_foramen(gl_ctx):
    """In the last image of the correct attempt (submental-oblique) the steel needle is the darkest
    thing along its shaft, its tip projects inside the foramen's opening, and the foramen ovale shows
    as a hole: less bone on the rays through it than on those through the rim around it."""
    from chainsim.game.render.renderer import Renderer

    app, events, last = _correct_app()
    try:
        _play(app, events, last + 0.3)
        a = app.resource(Assessment).values
        assert a["target"] == "foramen_ovale_left" and a["xray_view"] == "submental" and a["xray_shots"] == 3
        fr = app.resource(Renderer).fluoro
        path, cam, n = fr.path, fr.camera, fr.size
        anat = tomllib.loads((PACK / "anatomy.toml").read_text())
        fo = np.asarray(anat["foramina"]["left"]["centre"])
        radius = anat["foramina"]["left"]["radius_mm"]
        tip = np.asarray(a["tip"])
        entry = np.asarray(a["landmarks"][0])
        mm_per_px = 2 * np.tan(np.radians(cam.fov / 2)) * np.linalg.norm(cam.eye - cam.target) / n
        (fx, fy), (tx, ty) = _project(cam, [fo, tip], n)
        # the tip lies on the opening in the picture
        assert np.hypot(tx - fx, ty - fy) * mm_per_px < radius
        # the shaft: every point from the skin to the tip is far darker (more attenuation) than 3 mm beside it
        shaft = _project(cam, [entry + s * (tip - entry) for s in np.linspace(0.5, 0.95, 12)], n)
        u = shaft[-1] - shaft[0]
        side = np.array([-u[1], u[0]]) / np.linalg.norm(u)
        for x, y in shaft:
            on = path[int(y), int(x)]
            beside = [path[int(y + k * side[1] * 3 / mm_per_px), int(x + k * side[0] * 3 / mm_per_px)] for k in (-1, 1)]
            assert on > max(beside) + 2.0  # steel: about 2 / mm over ~1.8 mm of shaft
        # the foramen: the opening (away from the needle's shadow) against the bony rim around it
        yy, xx = np.mgrid[0:n, 0:n]
        r = np.hypot(xx + 0.5 - fx, yy + 0.5 - fy) * mm_per_px
        # the needle's shadow runs from the tip back toward the skin; past the tip the opening is clear
        rel = np.c_[xx.ravel() + 0.5 - tx, yy.ravel() + 0.5 - ty] * mm_per_px
        ahead = rel @ (u / np.linalg.norm(u)) > 1.0
        off_needle = ((np.abs(rel @ side) > 2.0) | ahead).reshape(n, n)
        hole = path[(r < 0.7 * radius) & off_needle]
        rim = path[(r > 1.4 * radius) & (r < 2.2 * radius) & off_needle]
        assert hole.size > 20 and rim.size > 100
        assert np.median(rim) - np.median(hole) > 0.3  # about 4 mm of bone missing (0.08 / mm)
        # and on the monitor: the oval is lighter than its rim, more so with the window narrowed on it
        shown = fr.image_rgb()[..., 0].astype(float)
        hole_mask, rim_mask = (r < 0.7 * radius) & off_needle, (r > 1.4 * radius) & (r < 2.2 * radius) & off_needle
        seen = np.median(shown[hole_mask]) - np.median(shown[rim_mask])
        assert seen >= 12.0, seen  # grey levels of 255
        narrow = grey(path, window=0.5).astype(float)
        assert np.median(narrow[hole_mask]) - np.median(narrow[rim_mask]) > 1.5 * seen
        assert n == 512  # the small monitor's image
    finally:
        app.close()


def test_the_big_xray_key_enlarges_the_monitor_and_its_images():
    """v (the Big X-ray button): the C-arm view takes the surgeon's view's place, then the whole window,
    then the layout comes back; a large view gets images of 1024 pixels a side."""
    from chainsim.game.render.radiograph import IMAGE_PX, LARGE_IMAGE_PX, image_size
    from chainsim.systems.view.cameras import ViewState

    app = open_app(str(PACK))
    try:
        vs = app.resource(ViewState)
        carm0, surgeon0 = vs.get("carm").rect, vs.get("surgeon").rect
        pending = app.resource(PendingInput)
        pending.push(app.time.sim_time, Widget("enlarge:carm", None))
        app.update(app.time.dt)
        assert vs.get("carm").rect == surgeon0 and vs.get("surgeon").rect == carm0
        assert image_size(min(surgeon0.w, surgeon0.h)) == LARGE_IMAGE_PX and image_size(carm0.w) == IMAGE_PX
        pending.push(app.time.sim_time, Widget("enlarge:carm", None))
        app.update(app.time.dt)
        full = vs.get("carm").rect
        assert (full.w, full.h) == vs.size and vs.at(full.w // 2, full.h // 2).name == "carm"
        pending.push(app.time.sim_time, Widget("enlarge:carm", None))
        app.update(app.time.dt)
        assert vs.get("carm").rect == carm0 and vs.get("surgeon").rect == surgeon0
    finally:
        app.close()


def test_window_level_narrows_and_moves_the_grey_window():
    rng = np.random.default_rng(3)
    path = np.clip(rng.normal(2.0, 0.5, (64, 64)), 0.5, None)
    auto, narrow, darker = grey(path), grey(path, window=0.5), grey(path, level=0.3)
    inside = auto > 0
    assert np.std(narrow[inside].astype(float)) > np.std(auto[inside].astype(float))
    assert np.mean(darker[inside].astype(float)) > np.mean(auto[inside].astype(float))  # centre up: L reads lighter


def test_the_image_stays_frozen_until_the_next_shot(gl_ctx):
    from chainsim.game.render.renderer import Renderer

    app, events, last = _correct_app()
    try:
        # up to just before the final submental image: the lateral one, halfway in, is on the view
        first_final = max(t for t, e in events if isinstance(e, Widget) and e.name == "xray_take")
        _play(app, [e for e in events if e[0] < first_final], first_final - 0.01)
        fr = app.resource(Renderer).fluoro
        shown, image_id = fr.path.copy(), fr.image_id
        # the needle went on in after that image; a frame drawn now still shows the image as taken
        from chainsim.game.render.render_system import draw

        draw(app)
        assert fr.image_id == image_id and np.array_equal(fr.path, shown)
        _play(app, [(first_final + 0.01, Widget("xray_take", None))], 0.1)
        draw(app)
        assert fr.image_id > image_id and not np.array_equal(fr.path, shown)
    finally:
        app.close()


def test_snapshot_of_the_fluoro_scene_shows_bone_and_needle(tmp_path):
    out = tmp_path / "xray.png"
    r = subprocess.run(
        [sys.executable, "-m", "game", "snapshot", "prp", "--scene", "fluoro", "--out", str(out), "--size", "1000x600"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr
    img = np.asarray(Image.open(out).convert("L")).astype(int)
    # the C-arm view fills the left 60 %: a round field, black around it
    view = img[:, :600]
    h, w = view.shape
    yy, xx = np.mgrid[0:h, 0:w]
    rr = np.hypot(xx - w / 2, yy - h / 2)
    field = view[rr < 0.45 * min(h, w)]
    assert np.median(view[(rr > 0.52 * min(h, w)) & (yy > 30) & (yy < h - 30)]) < 10  # outside the field
    # bone: a wide spread of greys inside the field (soft tissue alone would be nearly flat)
    lo, hi = np.percentile(field, [5, 95])
    assert hi - lo > 90
    # the needle: a long, nearly black, straight streak
    dark = (view < 25) & (rr < 0.45 * min(h, w))
    assert dark.sum() > 400
    ys, xs = np.nonzero(dark)
    span = max(np.ptp(xs), np.ptp(ys))
    assert span > 0.25 * min(h, w)


def test_a_new_attempt_starts_without_the_last_attempts_image(gl_ctx, tmp_path):
    """After Save and Reset the C-arm view says "No image yet" with its 0 images, not the last attempt's image."""
    from chainsim.game.render.render_system import draw
    from chainsim.game.render.renderer import Renderer
    from chainsim.game.trainer.headless import build_app

    settings = {"db": str(tmp_path / "r.sqlite3"), "class": "c1", "trainee": "ann"}
    app = build_app(str(PACK), render=True, headless=True, settings=settings)
    events = load_script(PACK / "scripts" / "correct.toml")
    try:
        _play(app, events, max(t for t, _ in events) + 0.1)
        draw(app)
        fr = app.resource(Renderer).fluoro
        assert fr.shown and fr.image_rgb() is not None
        t = app.time.sim_time
        turn = Widget("rotate_horizontal", 1.0)
        _play(app, [(t + 0.01, Widget("save", None)), (t + 0.05, Widget("reset", None)), (t + 0.1, turn)], 0.3)
        draw(app)
        assert app.resource(Assessment).values.get("saved")
        assert not fr.shown and fr.image_rgb() is None
        _play(app, [(app.time.sim_time + 0.01, Widget("xray_take", None))], 0.1)
        draw(app)
        assert fr.shown  # the new attempt's own image
    finally:
        app.close()


def test_window_level_is_dragged_shown_with_its_values_and_reset_by_a_right_click():
    """A right-drag in the C-arm view turns the monitor's window/level, the view says the values and how to
    reset them, and a right-click (no drag) puts them back to automatic."""
    from chainsim.components.input_events import MouseButton, MouseDrag
    from chainsim.game.render import panelview
    from chainsim.game.render.render_system import fluoro_draw
    from chainsim.systems.view.cameras import ViewState

    app = open_app(str(PACK))
    try:
        vs = app.resource(ViewState)
        r = vs.get("carm").rect
        x, y = r.x + r.w / 2, r.y + r.h / 2
        pending, t = app.resource(PendingInput), app.time.sim_time
        pending.extend([(t, MouseButton(x, y, "right", True)), (t, MouseDrag(x + 40, y + 20, 40, 20, "right")),
                        (t, MouseButton(x + 40, y + 20, "right", False))])  # fmt: skip
        app.update(app.time.dt)
        assert vs.xray_window > 1.0 and vs.xray_level > 0.0
        with app.active():
            draw = fluoro_draw(app)
        said = panelview.window_level_text(draw.window, draw.level)
        assert said == f"W x{vs.xray_window:.2f}  L {vs.xray_level:+.2f}  (right-click: reset)"
        t = app.time.sim_time
        pending.extend([(t, MouseButton(x, y, "right", True)), (t, MouseButton(x, y, "right", False))])
        app.update(app.time.dt)
        assert (vs.xray_window, vs.xray_level) == (1.0, 0.0)
        assert panelview.window_level_text(vs.xray_window, vs.xray_level) == ""
    finally:
        app.close()


def test_the_whole_window_x_ray_carries_the_step_text_and_the_pages_at_full_size():
    """With the C-arm view over the whole window (Big X-ray twice) the other views have no room: the step
    text, the messages and F1's pages go to the X-ray view, as wide as the window allows, at 1024x768."""
    from chainsim.systems.view.cameras import ViewState, main_view
    from chainsim.systems.view.ui import docbox

    app = open_app(str(PACK), size=(1024, 768))
    try:
        vs = app.resource(ViewState)
        assert main_view(vs).name == "surgeon"
        pending = app.resource(PendingInput)
        for _ in range(2):
            pending.push(app.time.sim_time, Widget("enlarge:carm", None))
            app.update(app.time.dt)
        assert main_view(vs).name == "carm" and (vs.get("carm").rect.w, vs.get("carm").rect.h) == (1024, 768)
        box = docbox.box(main_view(vs).rect)
        assert box.w > 0.7 * 1024 and box.h > 0.7 * 768
        pending.push(app.time.sim_time, Widget("enlarge:carm", None))
        app.update(app.time.dt)
        assert main_view(vs).name == "surgeon"
    finally:
        app.close()

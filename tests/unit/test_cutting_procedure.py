"""The cutting procedure's instruments driven event by event (thesis 4.5.2): forceps grip, speed, push
and release; scissors on the layer they start on; mouse drags in the frozen controller view; the
tool's best view; reset; wireframe; and the errors a pack or script can cause."""

from __future__ import annotations

import shutil
from pathlib import Path

import esper
import numpy as np
import pytest

from chainsim.components.core import Transform
from chainsim.components.hud import HudState
from chainsim.components.input_events import MouseButton, MouseDrag, MouseMove, PickPoint, Widget
from chainsim.components.resources import Assessment, EntityIndex, PendingInput
from chainsim.game.trainer.headless import build_app
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures.cutting.state import parse_point
from chainsim.systems.procedures.cutting.tools import Forceps, Scissors
from chainsim.systems.tissue.deformable import Deformable

PACK = Path(__file__).resolve().parents[2] / "assets" / "cutting"
CORNER = (40.0, 30.0, 0.0)


def make(ref: str = "cutting", events=()):
    app = build_app(ref)
    app.resource(PendingInput).extend(list(events))
    return app


def steps(app, n: int) -> None:
    for _ in range(n):
        app.update(app.time.dt)


def comp(app, name: str, kind):
    with app.active():
        return esper.component_for_entity(app.resource(EntityIndex)[name], kind)


def nearest(d: Deformable, point) -> int:
    return int(np.argmin(np.sum((d.body.rest - np.asarray(point)) ** 2, axis=1)))


@pytest.fixture
def app():
    a = make()
    yield a
    a.close()


def test_parse_point():
    assert parse_point("1, 2.5, -3", "w").tolist() == [1.0, 2.5, -3.0]
    assert parse_point("1 2 3", "w").tolist() == [1.0, 2.0, 3.0]
    for bad in ("1, 2", "a, b, c", "1, 2, nan", 4.0, None):
        with pytest.raises(UserError, match="x, y, z"):
            parse_point(bad, "widget 'pull'")


def test_forceps_tip_follows_the_hand_at_its_speed(app):
    app.resource(PendingInput).extend(
        [(0.0, Widget("forceps")), (0.0, PickPoint("dura", CORNER)), (0.0, Widget("pull", "40, 30, 30"))]
    )
    steps(app, 1)
    f = comp(app, "forceps", Forceps)
    d = comp(app, "dura", Deformable)
    c = nearest(d, CORNER)
    assert f.held_element == c
    one = f.speed * app.time.dt
    assert d.body.positions[c] == pytest.approx([40.0, 30.0, one], abs=1e-9)
    steps(app, 9)
    assert d.body.positions[c] == pytest.approx([40.0, 30.0, 10 * one], abs=1e-9)


def test_push_presses_the_held_element_into_the_tissue_along_its_normal(app):
    app.resource(PendingInput).extend(
        [(0.0, Widget("forceps")), (0.0, PickPoint("dura", (0.0, 0.0, 0.0))), (0.0, Widget("push", 3.0))]
    )
    steps(app, 30)
    d = comp(app, "dura", Deformable)
    c = nearest(d, (0.0, 0.0, 0.0))
    assert d.body.positions[c] == pytest.approx(d.body.rest[c] - [0.0, 0.0, 3.0], abs=1e-9)
    app.resource(PendingInput).push(app.time.sim_time, Widget("push"))  # the button: 2 mm more
    steps(app, 30)
    # along the normal of the surface as it is now (tilted a little by the dent), pressed in: nearly
    # straight down again, 2 mm further
    assert d.body.positions[c][2] == pytest.approx(d.body.rest[c][2] - 5.0, abs=5e-3)
    assert np.linalg.norm(d.body.positions[c] - d.body.rest[c]) == pytest.approx(5.0, abs=2e-2)


def test_release_leaves_the_tissue_where_it_is(app):
    app.resource(PendingInput).extend(
        [
            (0.0, Widget("forceps")),
            (0.0, PickPoint("dura", CORNER)),
            (0.0, Widget("pull_by", "0, 0, 6")),
            (0.5, Widget("release")),
        ]
    )
    steps(app, 80)
    d = comp(app, "dura", Deformable)
    f = comp(app, "forceps", Forceps)
    assert f.held_entity == -1 and len(d.body.held) == 0
    assert d.body.positions[nearest(d, CORNER)][2] == pytest.approx(6.0, abs=1e-9)
    v = app.resource(Assessment).values
    assert v["forceps_uses"] == 1
    assert v["forceps_time_s"] == pytest.approx(0.5, abs=app.time.dt)


def test_the_fixed_edge_cannot_be_gripped(app):
    app.resource(PendingInput).extend([(0.0, Widget("forceps")), (0.0, PickPoint("dura", (0.0, -30.0, 0.0)))])
    steps(app, 2)
    assert comp(app, "forceps", Forceps).held_entity == -1
    assert any("fixed" in text for text, _ in app.resource(HudState).messages)


def test_scissors_cut_only_the_layer_the_stroke_started_on(app):
    pts = [(-20.0, 10.0, -2.5), (0.0, 10.0, -2.5), (20.0, 10.0, -2.5)]
    app.resource(PendingInput).extend([(0.0, Widget("scissors"))] + [(0.0, PickPoint("arachnoid", p)) for p in pts])
    steps(app, 2)
    low, top = comp(app, "arachnoid", Deformable), comp(app, "dura", Deformable)
    assert top.body.alive.all()
    dead = low.body.graph.links[~low.body.alive]
    assert len(dead) > 20
    ys = low.body.rest[dead][:, :, 1]
    assert np.all((ys.min(axis=1) <= 10.0) & (ys.max(axis=1) >= 10.0))  # every cut link crossed y = 10
    v = app.resource(Assessment).values
    assert v["layers_cut"] == ["arachnoid"] and v["cut_length_mm"] == pytest.approx(40.0, abs=1e-6)


def test_reset_restores_both_layers_and_the_steps(app):
    app.resource(PendingInput).extend(
        [
            (0.0, Widget("scissors")),
            (0.0, PickPoint("dura", (0.6, 30.0, 0.0))),
            (0.0, PickPoint("dura", (0.6, 0.0, 0.0))),
            (0.1, Widget("forceps")),
            (0.1, PickPoint("dura", CORNER)),
            (0.1, Widget("pull_by", "0, 0, 12")),
            (0.6, Widget("reset")),
        ]
    )
    steps(app, 80)
    v = app.resource(Assessment).values
    assert v["resets"] == 1
    assert v["links_cut"] == 0 and v["elements_moved"] == 0 and v["cut_length_mm"] == 0.0
    assert v["steps_done"] == [] and v["step"] == "pull"
    for name in ("dura", "arachnoid"):
        d = comp(app, name, Deformable)
        assert np.array_equal(d.body.positions, d.body.rest) and d.body.alive.all() and len(d.body.held) == 0
    assert comp(app, "forceps", Forceps).held_entity == -1


def test_choosing_a_tool_moves_the_frozen_view_only(app):
    from chainsim.systems.view.cameras import ViewState

    vs = app.resource(ViewState)
    viewer0 = vs.get("viewer").camera.eye.copy()
    app.resource(PendingInput).extend([(0.0, Widget("scissors"))])
    steps(app, 1)
    ctl = vs.get("controller").camera
    assert ctl.pitch == 75.0 and ctl.forward[2] < -0.9  # looking down on the tissue to cut
    app.resource(PendingInput).push(app.time.sim_time, Widget("forceps"))
    steps(app, 1)
    assert ctl.pitch == 35.0 and -0.7 < ctl.forward[2] < -0.4  # oblique, to pull up and back
    assert np.array_equal(vs.get("viewer").camera.eye, viewer0)
    # the whole tissue is in the controller's frame
    vp = vs.get("controller")
    corners = np.array([[x, y, 0.0] for x in (-40.0, 40.0) for y in (-30.0, 30.0)])
    px = ctl.project(corners, vp.rect)
    assert np.all((px[:, 0] > vp.rect.x) & (px[:, 0] < vp.rect.x + vp.rect.w))
    assert np.all((px[:, 1] > vp.rect.y) & (px[:, 1] < vp.rect.y + vp.rect.h))


def _pixel(app, viewport: str, point):
    from chainsim.systems.view.cameras import ViewState

    vp = app.resource(ViewState).get(viewport)
    x, y, _ = vp.camera.project(np.asarray([point], float), vp.rect)[0]
    return float(np.floor(x)), float(np.floor(y))


def test_a_mouse_drag_in_the_controller_pulls_and_lets_go(app):
    app.resource(PendingInput).push(0.0, Widget("forceps"))
    steps(app, 1)
    x, y = _pixel(app, "controller", (39.0, 29.0, 0.0))  # just inside the corner
    t = app.time.sim_time
    ev = [(t, MouseButton(x, y, "left", True))]
    for k in range(1, 9):
        ev.append((t + 0.01 * k, MouseDrag(x, y + 5 * k, 0.0, 5.0, "left")))
    ev.append((t + 0.1, MouseButton(x, y + 40, "left", False)))
    app.resource(PendingInput).extend(ev)
    steps(app, 150)
    d = comp(app, "dura", Deformable)
    f = comp(app, "forceps", Forceps)
    c = nearest(d, CORNER)
    assert f.uses == 1 and f.held_entity == -1 and len(d.body.held) == 0  # let go at the end of the drag
    assert d.body.positions[c][2] > 5.0  # dragging up the screen lifted the corner
    assert np.array_equal(d.body.positions[d.body.fixed], d.body.rest[d.body.fixed])


def test_a_mouse_drag_with_the_scissors_cuts_the_top_layer(app):
    app.resource(PendingInput).push(0.0, Widget("scissors"))
    steps(app, 1)
    a = _pixel(app, "controller", (0.6, 28.0, 0.0))
    b = _pixel(app, "controller", (0.6, -20.0, 0.0))
    t = app.time.sim_time
    n = 12
    ev = [(t, MouseButton(a[0], a[1], "left", True))]
    for k in range(1, n + 1):
        p = (a[0] + (b[0] - a[0]) * k / n, a[1] + (b[1] - a[1]) * k / n)
        ev.append((t + 0.01 * k, MouseDrag(round(p[0]), round(p[1]), 0.0, 0.0, "left")))
    ev.append((t + 0.2, MouseButton(round(b[0]), round(b[1]), "left", False)))
    app.resource(PendingInput).extend(ev)
    steps(app, 40)
    top, low = comp(app, "dura", Deformable), comp(app, "arachnoid", Deformable)
    assert low.body.alive.all()
    dead = top.body.graph.links[~top.body.alive]
    assert len(dead) > 15
    mid = top.body.rest[dead].mean(axis=1)
    assert np.all(np.abs(mid[:, 0] - 0.6) < 2.5) and mid[:, 1].min() > -23.0 and mid[:, 1].max() < 31.0
    s = comp(app, "scissors", Scissors)
    assert s.uses == 1 and s.stroke_entity == -1 and s.path_length > 40.0


def test_the_idle_instrument_follows_the_cursor_over_the_tissue(app):
    app.resource(PendingInput).push(0.0, Widget("scissors"))
    steps(app, 1)
    x, y = _pixel(app, "controller", (-10.0, 5.0, 0.0))
    app.resource(PendingInput).push(app.time.sim_time, MouseMove(x, y))
    steps(app, 1)
    pos = comp(app, "scissors", Transform).position
    assert pos[:2] == pytest.approx([-10.0, 5.0], abs=0.6)  # within a pixel of the cursor
    assert 0.0 < pos[2] < 1.0  # drawn just above the top layer
    gone = _pixel(app, "controller", (0.0, 80.0, 0.0))  # off the tissue: the tool stays where it was
    app.resource(PendingInput).push(app.time.sim_time, MouseMove(*gone))
    steps(app, 1)
    assert comp(app, "scissors", Transform).position == pytest.approx(pos)


def test_wireframe_switch_draws_links_and_leaves_the_pack_alone(app):
    from chainsim.components.core import Wireframe
    from chainsim.components.resources import PackResource

    dura = app.resource(EntityIndex)["dura"]
    app.resource(PendingInput).push(0.0, Widget("wireframe", True))
    steps(app, 1)
    with app.active():
        assert esper.has_component(dura, Wireframe)
    assert app.resource(Assessment).values["wireframe"] is True
    assert app.resource(PackResource).pack.section("materials")["dura"].get("wireframe", False) is False
    app.resource(PendingInput).push(app.time.sim_time, Widget("wireframe", False))
    steps(app, 1)
    with app.active():
        assert not esper.has_component(dura, Wireframe)


def test_a_bad_pull_target_is_a_user_error(app):
    app.resource(PendingInput).extend(
        [(0.0, Widget("forceps")), (0.0, PickPoint("dura", CORNER)), (0.0, Widget("pull", "40, 30"))]
    )
    with pytest.raises(UserError, match="widget 'pull'"):
        steps(app, 1)


def test_touching_without_a_tool_does_nothing(app):
    app.resource(PendingInput).push(0.0, PickPoint("dura", CORNER))
    steps(app, 2)
    d = comp(app, "dura", Deformable)
    assert np.array_equal(d.body.positions, d.body.rest)
    assert any("tool" in text for text, _ in app.resource(HudState).messages)


def test_a_pack_without_forceps_is_refused(tmp_path):
    dst = tmp_path / "cutting"
    shutil.copytree(PACK, dst)
    text = (dst / "pack.toml").read_text()
    head = text.index("[entities.forceps.forceps]\n")
    text = text[:head] + text[text.index("\n[", head) + 1 :]  # the whole [forceps] table
    (dst / "pack.toml").write_text(text)
    with pytest.raises(UserError, match=r"exactly one entity with a \[forceps\] table"):
        build_app(str(dst))


def test_steps_complete_on_the_events_the_pack_declares(tmp_path):
    """A step says in data what completes it: a 3 mm carry completes a pull step that asks for 2 mm,
    not the shipped one that asks for 5 mm."""
    dst = tmp_path / "cutting"
    shutil.copytree(PACK, dst)
    text = (dst / "pack.toml").read_text()
    assert 'done_on = ["carried:5"]' in text
    (dst / "pack.toml").write_text(text.replace('done_on = ["carried:5"]', 'done_on = ["carried:2"]'))
    carry = [(0.0, Widget("forceps")), (0.0, PickPoint("dura", CORNER)), (0.0, Widget("pull_by", "0, 0, 3"))]
    done = {}
    for ref in ("cutting", str(dst)):
        a = make(ref, carry)
        try:
            steps(a, 60)
            done[ref] = a.resource(Assessment).values["steps_done"]
        finally:
            a.close()
    assert done["cutting"] == [] and done[str(dst)] == ["pull"]


@pytest.mark.parametrize("bad", ["carried", "carried:x", "lifted:5", "cut:-1"])
def test_a_step_event_the_procedure_cannot_read_is_one_line(tmp_path, bad):
    dst = tmp_path / "cutting"
    shutil.copytree(PACK, dst)
    text = (dst / "pack.toml").read_text()
    (dst / "pack.toml").write_text(text.replace('done_on = ["cut:20"]', f'done_on = ["{bad}"]'))
    with pytest.raises(UserError, match=r"steps\.cut\.done_on: .* is not an event of the cutting procedure"):
        build_app(str(dst))


def test_a_pull_far_past_what_the_layer_allows_leaves_every_link_in_its_limits(app):
    """The layers ask for exact limits: carried 60 mm up with its far edge fixed, the dura stops where
    its links allow (the grab falls short), and no link stretches past alpha_max (1.6) as it did with
    the cascade alone (8.8x here)."""
    app.resource(PendingInput).extend(
        [(0.0, Widget("forceps")), (0.0, PickPoint("dura", CORNER)), (0.0, Widget("pull_by", "0, 0, 60"))]
    )
    steps(app, 300)
    v = app.resource(Assessment).values
    assert v["max_stretch_by_layer"]["dura"] <= 1.6 + 1e-6
    d = comp(app, "dura", Deformable)
    assert np.all(np.isfinite(d.body.positions)) and d.body.positions[nearest(d, CORNER)][2] > 5.0

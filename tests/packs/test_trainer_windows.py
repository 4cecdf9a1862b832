"""The cutting trainer's and the ChainMail demos' windows as a person meets them (headless App, the
same view system and HUD the window draws): both views framed on the tissue at start, after a tool
change and after a resize; a Help button and F1 that reach the pack's pages; on-screen step text;
the demo's marked element, its reset and its panel title."""

from __future__ import annotations

import esper
import numpy as np
import pytest

from chainsim.components.core import Marker, PolyLine, Transform
from chainsim.components.hud import HudState
from chainsim.components.input_events import Key, MouseButton, Resize, Widget
from chainsim.components.resources import EntityIndex, PackResource, PendingInput
from chainsim.game.trainer.headless import build_app
from chainsim.systems.procedures.cutting.state import CuttingState
from chainsim.systems.procedures.cutting.steps import tissue_bounds
from chainsim.systems.tissue.deformable import Deformable, Pull
from chainsim.systems.view.cameras import FIT_MARGIN, FIT_TOP, FIT_TOP_MAIN, ViewState, main_view
from chainsim.systems.view.ui import docbox
from chainsim.systems.view.ui.viewports import box_corners


def send(app, *events, steps: int = 3) -> None:
    t = app.time.sim_time + app.time.dt / 2
    app.resource(PendingInput).extend([(t, ev) for ev in events])
    app.run_steps(steps)


def inside(vs: ViewState, vp, lo, hi, slack: float = 0.5) -> bool:
    """Every corner of the box lo..hi projects inside the view, clear of its caption (and, in the
    main view, of the step text)."""
    r = vp.rect
    top = FIT_TOP_MAIN if vp is main_view(vs) else FIT_TOP
    p = vp.camera.project(box_corners(lo, hi), r)
    m = FIT_MARGIN - slack
    return bool(
        np.all(p[:, 0] >= r.x + m)
        and np.all(p[:, 0] <= r.x + r.w - m)
        and np.all(p[:, 1] >= r.y + m)
        and np.all(p[:, 1] <= r.y + r.h - m - top)
    )


def views_3d(vs: ViewState):
    return [vp for vp in vs.viewports if vp.kind in ("orbit", "fixed")]


@pytest.fixture()
def cutting():
    app = build_app("cutting")
    yield app
    app.close()


@pytest.fixture()
def demo():
    app = build_app("chainmail-demo")
    yield app
    app.close()


# -- framing ----------------------------------------------------------------------------------------


@pytest.mark.parametrize("pack", ["cutting", "chainmail-demo"])
def test_both_views_show_the_whole_tissue_at_start(pack):
    app = build_app(pack)
    try:
        vs = app.resource(ViewState)
        lo, hi = vs.scene_box
        shown = views_3d(vs)
        assert len(shown) == 2
        for vp in shown:
            assert inside(vs, vp, lo, hi), vp.name
            # and fills it: not a speck in the middle (the box spans most of the width or the height)
            p = vp.camera.project(box_corners(lo, hi), vp.rect)
            span = max(np.ptp(p[:, 0]) / vp.rect.w, np.ptp(p[:, 1]) / (vp.rect.h - FIT_TOP_MAIN))
            assert span > 0.8, (vp.name, span)
    finally:
        app.close()


def test_the_cutting_tool_views_frame_the_tissue_and_the_brain(cutting):
    vs = cutting.resource(ViewState)
    st = cutting.resource(CuttingState)
    for tool in ("forceps", "scissors"):
        send(cutting, Widget(tool))
        ctl = vs.get("controller")
        with cutting.active():
            lo, hi = tissue_bounds(st)
        assert inside(vs, ctl, np.minimum(lo, vs.scene_box[0]), np.maximum(hi, vs.scene_box[1])), tool
    assert vs.get("controller").camera.pitch == 75.0  # the scissors' top-down view


def test_a_resize_frames_the_views_again_unless_the_trainee_moved_one(cutting):
    vs = cutting.resource(ViewState)
    viewer = vs.get("viewer")
    viewer.camera.rotate(40, 0)  # the trainee turned the viewer
    turned = viewer.camera.yaw
    send(cutting, Resize(900, 700))
    assert viewer.camera.yaw == turned  # left where the trainee put it
    assert inside(vs, vs.get("controller"), *vs.scene_box)
    send(cutting, Widget("camera:reset"))  # Reset view: back to the framed view, for this size
    assert inside(vs, viewer, *vs.scene_box)


# -- help -------------------------------------------------------------------------------------------


def test_the_cutting_help_button_opens_the_page_of_the_current_step(cutting):
    hud = cutting.resource(HudState)
    assert "help" in {w["name"] for w in cutting.resource(PackResource).layout["widgets"]}
    assert hud.step_title.startswith("1.") and hud.step_instruction
    send(cutting, Key("h", True), Key("h", False))
    assert hud.doc_open and hud.doc_name == "trainer"
    send(cutting, Key("h", True), Key("h", False))
    assert not hud.doc_open


def test_f1_leads_on_to_the_help_pages(cutting):
    from chainsim.systems.view.cameras import page_buttons

    hud = cutting.resource(HudState)
    send(cutting, Key("f1", True), Key("f1", False))
    assert hud.doc_open and hud.doc_name == "keys"
    assert page_buttons(hud) == docbox.KEY_PAGE_BUTTONS
    vs = cutting.resource(ViewState)
    b = docbox.box(main_view(vs).rect)
    r = docbox.buttons(b, page_buttons(hud))["docs"]
    x, y = r.x + r.w / 2, r.y + r.h / 2
    send(cutting, MouseButton(x, y, "left", True), MouseButton(x, y, "left", False))
    assert hud.doc_open and hud.doc_name == "trainer"


def test_the_key_page_names_the_help_pages_and_the_trainers_own_mouse_actions(cutting):
    from chainsim.game.render.render_system import page

    send(cutting, Key("f1", True), Key("f1", False))
    _title, text, buttons = page(cutting)
    assert buttons == {"docs": True, "close": True}
    assert "Using the cutting trainer" in text and "What the trainer models" in text
    assert "Controller" in text and "1 mm a notch" in text


def test_the_demo_help_button_opens_its_page(demo):
    hud = demo.resource(HudState)
    send(demo, Widget("help"))
    assert hud.doc_open and hud.doc_name == "about"


# -- the ChainMail demo -----------------------------------------------------------------------------


def marked(app):
    index = app.resource(EntityIndex)
    ent = index.get("patch")
    mark = index.get("patch.marked")
    return ent, mark


def test_the_demo_marks_the_element_its_pull_drags(demo):
    ent, mark = marked(demo)
    assert mark is not None
    with demo.active():
        mk = esper.component_for_entity(mark, Marker)
        d = esper.component_for_entity(ent, Deformable)
        p = esper.component_for_entity(ent, Pull)
        assert mk.visible and mk.radius > 0
        assert np.allclose(esper.component_for_entity(mark, Transform).position, d.body.positions[p.resolved])
        line = esper.component_for_entity(mark, PolyLine)
        assert line.visible and np.allclose(line.points[-1], p.waypoints[-1])  # where it will go
    send(demo, Widget("pull"), steps=90)
    with demo.active():
        assert p.done
        assert np.allclose(esper.component_for_entity(mark, Transform).position, d.body.positions[p.resolved])
        assert np.allclose(d.body.positions[p.resolved], p.waypoints[-1])  # the marker went with it


def test_the_demo_reset_puts_the_tissue_back_and_pull_works_again(demo):
    ent, _ = marked(demo)
    hud = demo.resource(HudState)
    send(demo, Widget("pull"), steps=90)
    assert hud.step_title.startswith("2.")  # the next step's text once the pull is done
    send(demo, Key("r", True), Key("r", False))
    with demo.active():
        d = esper.component_for_entity(ent, Deformable)
        p = esper.component_for_entity(ent, Pull)
        assert np.array_equal(d.body.positions, d.body.rest) and not p.started
    assert hud.step_title.startswith("1.")
    send(demo, Widget("pull"), steps=90)
    with demo.active():
        assert p.done and np.allclose(d.body.positions[p.resolved], p.waypoints[-1])


def test_the_demo_panel_has_a_title_and_says_which_demo_runs(demo):
    vs = demo.resource(ViewState)
    panel = next(vp for vp in vs.viewports if vp.kind == "panel")
    assert panel.spec.get("title") and panel.spec["title"] != panel.name
    hud = demo.resource(HudState)
    demo.run_steps(1)
    assert hud.panel_text[0].startswith("Demo: patch")
    assert any("chainmail-demo/brain" in t for t in hud.panel_text)
    assert {"reset", "help", "pull"} <= {w["name"] for w in demo.resource(PackResource).layout["widgets"]}

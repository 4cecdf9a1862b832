"""Widget model (game/widgets.py) and the view system's widget routing (systems/view/cameras.py)."""

import esper
import numpy as np

from chainsim.components.core import MeshRef
from chainsim.components.input_events import Key, MouseButton, MouseDrag, Widget
from chainsim.components.resources import PendingInput
from chainsim.components.view_events import WidgetRefused
from chainsim.game.trainer.headless import build_app
from chainsim.systems.view.cameras import ViewState
from chainsim.systems.view.ui import widgets as wd
from chainsim.systems.view.ui.viewports import Rect


def _w(**kw):
    base = {
        "name": "w",
        "kind": "button",
        "label": "",
        "viewport": "",
        "rect": [0.0, 0.0, 0.0, 0.0],
        "value": False,
        "min": 0.0,
        "max": 1.0,
        "step": 0.0,
        "key": "",
        "key_value": 0.0,
        "layer": "",
        "help": "",
    }
    base.update(kw)
    return base


def test_automatic_column_is_top_down_inside_the_panel_without_overlap():
    panel = Rect(900, 0, 300, 700)
    specs = [_w(name=f"w{i}", kind=k) for i, k in enumerate(["button", "toggle", "slider", "dial", "light", "text"])]
    placed = wd.place(specs, panel)
    ys = [p.rect.y for p in placed]
    assert ys == sorted(ys, reverse=True)
    for a, b in zip(placed, placed[1:]):
        assert b.rect.y + b.rect.h <= a.rect.y
    for p in placed:
        assert panel.x <= p.rect.x and p.rect.x + p.rect.w <= panel.x + panel.w
        assert panel.y <= p.rect.y and p.rect.y + p.rect.h <= panel.y + panel.h


def test_explicit_rect_is_a_fraction_of_the_panel():
    placed = wd.place([_w(rect=[0.5, 0.0, 0.5, 0.1])], Rect(100, 0, 200, 400))
    assert placed[0].rect == Rect(200, 0, 100, 40)


def test_hit_skips_display_only_widgets():
    placed = wd.place([_w(name="l", kind="light"), _w(name="b")], Rect(0, 0, 200, 400))
    light, button = placed
    cx, cy = light.rect.x + 5, light.rect.y + 5
    assert wd.hit(placed, cx, cy) is None
    assert wd.hit(placed, button.rect.x + 5, button.rect.y + 5).spec["name"] == "b"


def test_slider_value_follows_x_and_clamps_and_snaps():
    p = wd.place([_w(kind="slider", min=-10.0, max=10.0, step=0.5)], Rect(0, 0, 220, 400))[0]
    x0, x1 = wd.track(p)
    assert wd.slider_value(p, x0) == -10.0
    assert wd.slider_value(p, x1 + 50) == 10.0
    mid = wd.slider_value(p, (x0 + x1) / 2 + 0.3)
    assert mid == 0.0


def test_key_and_click_values_per_kind():
    assert wd.key_value(_w(kind="toggle"), True) is False
    assert wd.key_value(_w(kind="button", key_value=-5.0), None) == -5.0
    assert wd.key_value(_w(kind="button"), None) is None
    assert wd.key_value(_w(kind="dial", min=0.0, max=90.0, step=5.0), 88.0) == 90.0
    assert wd.key_value(_w(kind="slider", min=0.0, max=1.0), 0.5) == 0.55
    dial = wd.place([_w(kind="dial", min=0.0, max=10.0, step=1.0)], Rect(0, 0, 200, 400))[0]
    assert wd.click_value(dial, dial.rect.x + 1, 5.0) == 4.0
    assert wd.click_value(dial, dial.rect.x + dial.rect.w - 1, 5.0) == 6.0


def test_widget_state_applies_and_respects_disabled():
    st = wd.WidgetState.from_layout(
        [_w(name="t", kind="toggle", value=True), _w(name="d", kind="dial", value=3.0, max=5.0), _w(name="b")]
    )
    assert st.values == {"t": True, "d": 3.0, "b": None}
    assert wd.apply_widget(st, "t", None) and st.values["t"] is False
    assert wd.apply_widget(st, "d", 99.0) and st.values["d"] == 5.0
    wd.apply_widget(st, "b", None)
    wd.apply_widget(st, "b", 2.0)
    assert st.presses["b"] == 2
    st.disable("d")
    assert wd.apply_widget(st, "d", 1.0) is False
    assert st.values["d"] == 5.0
    st.enable("d")
    assert wd.apply_widget(st, "d", 1.0) and st.values["d"] == 1.0


def _rod_visible(app):
    with app.active():
        return {r.mesh: r.visible for _, r in esper.get_component(MeshRef)}["rod"]


def _click_events(x, y):
    return [(0.0, MouseButton(x, y, "left", True)), (0.0, MouseButton(x, y, "left", False))]


def test_click_key_and_script_have_the_same_effect_on_a_layer_toggle():
    results = {}
    for how in ("click", "key", "script"):
        app = build_app("loop-demo")
        try:
            app.events.log = []
            vs: ViewState = app.resource(ViewState)
            p = vs.panels["panel"][0]
            cx, cy = p.rect.x + p.rect.w / 2, p.rect.y + p.rect.h / 2
            ev = {
                "click": _click_events(cx, cy),
                "key": [(0.0, Key("t", True))],
                "script": [(0.0, Widget("toggle_rod", False))],
            }[how]
            assert _rod_visible(app) is True
            app.resource(PendingInput).extend(ev)
            app.run_steps(2)
            results[how] = (
                _rod_visible(app),
                app.resource(wd.WidgetState).values["toggle_rod"],
                [e for e in app.events.log if isinstance(e, Widget)],
            )
        finally:
            app.close()
    assert results["click"][:2] == (False, False)
    assert results["key"][:2] == (False, False)
    assert results["script"][:2] == (False, False)
    assert results["click"][2] == [Widget("toggle_rod", False)]
    assert results["key"][2] == [Widget("toggle_rod", False)]


def test_disabled_widget_ignores_clicks():
    app = build_app("loop-demo")
    try:
        app.events.log = []
        app.resource(wd.WidgetState).disable("toggle_rod")
        p = app.resource(ViewState).panels["panel"][0]
        app.resource(PendingInput).extend(_click_events(p.rect.x + 3, p.rect.y + 3) + [(0.0, Key("t", True))])
        app.run_steps(2)
        assert _rod_visible(app) is True
        assert [e for e in app.events.log if isinstance(e, Widget)] == []
        # the click is answered, so a procedure can say why nothing happened
        assert [e for e in app.events.log if isinstance(e, WidgetRefused)] == [WidgetRefused("toggle_rod")]
    finally:
        app.close()


def test_left_drag_in_orbit_viewport_turns_its_camera_only():
    app = build_app("loop-demo")
    try:
        cam = app.resource(ViewState).get("main").camera
        yaw0, eye0 = cam.yaw, cam.eye.copy()
        app.resource(PendingInput).extend(
            [
                (0.0, MouseButton(300, 300, "left", True)),
                (0.0, MouseDrag(340, 300, 40, 0, "left")),
                (0.0, MouseButton(340, 300, "left", False)),
            ]
        )
        app.run_steps(2)
        assert cam.yaw != yaw0
        assert not np.allclose(cam.eye, eye0)
    finally:
        app.close()


def test_pointer_over_a_widget_selects_its_help():
    from chainsim.components.input_events import MouseMove

    app = build_app("loop-demo")
    try:
        vs: ViewState = app.resource(ViewState)
        p = vs.panels["panel"][0]
        app.resource(PendingInput).extend([(0.0, MouseMove(p.rect.x + 5, p.rect.y + 5))])
        app.update(0.0)
        assert vs.hover == "toggle_rod"
        app.resource(PendingInput).extend([(0.0, MouseMove(10, 10))])
        app.update(0.0)
        assert vs.hover == ""
    finally:
        app.close()


def test_scroll_over_a_dial_steps_it_and_resize_keeps_the_layout(tmp_path):
    from chainsim.components.input_events import Resize, Scroll

    root = tmp_path / "dialpack"
    root.mkdir()
    (root / "pack.toml").write_text(
        """
[pack]
name = "dialpack"
format = 1
[settings]
window_size = [800.0, 600.0]
[layouts.l]
[[layouts.l.viewports]]
name = "main"
kind = "orbit"
rect = [0.0, 0.0, 0.7, 1.0]
[[layouts.l.viewports]]
name = "panel"
kind = "panel"
rect = [0.7, 0.0, 0.3, 1.0]
[[layouts.l.widgets]]
name = "angle"
kind = "dial"
min = -10.0
max = 10.0
step = 2.0
value = 9.0
""",
        encoding="utf-8",
    )
    app = build_app(str(root))
    try:
        app.events.log = []
        vs: ViewState = app.resource(ViewState)
        p = vs.panels["panel"][0]
        cx, cy = p.rect.x + p.rect.w / 2, p.rect.y + p.rect.h / 2
        app.resource(PendingInput).extend(
            [(0.0, Scroll(cx, cy, 1.0)), (0.0, Scroll(cx, cy, -1.0)), (0.0, Scroll(cx, cy, -1.0))]
        )
        app.update(0.0)
        assert [e for e in app.events.log if isinstance(e, Widget)] == [
            Widget("angle", 10.0),
            Widget("angle", 8.0),
            Widget("angle", 6.0),
        ]
        assert app.resource(wd.WidgetState).values["angle"] == 6.0
        app.resource(PendingInput).extend([(0.0, Resize(400, 300))])
        app.update(0.0)
        assert vs.get("main").rect == Rect(0, 0, 280, 300)
        assert vs.get("panel").rect == Rect(280, 0, 120, 300)
        q = vs.panels["panel"][0]
        assert vs.get("panel").rect.x < q.rect.x and q.rect.y + q.rect.h <= 300
    finally:
        app.close()

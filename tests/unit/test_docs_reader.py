"""The in-app docs reader: the reading step shows its page, Help toggles it, page keys scroll it."""

from __future__ import annotations

from chainsim.components.hud import HudState
from chainsim.components.input_events import Key, PickPoint, Widget
from chainsim.components.resources import PackResource, PendingInput
from chainsim.game.trainer.headless import build_app


def test_reading_step_opens_its_page_and_help_toggles_it():
    app = build_app("prp")
    try:
        app.run_steps(1)
        h = app.resource(HudState)
        assert h.doc_open and h.doc_name == "background"
        pending = app.resource(PendingInput)
        pending.extend([(0.02, Key("pagedown", True)), (0.05, Widget("help")), (0.1, Widget("help"))])
        app.run_steps(4)
        assert h.doc_scroll == 12
        app.run_steps(6)
        assert not h.doc_open
        app.run_steps(6)
        assert h.doc_open and h.doc_scroll == 0
        # placing landmark 1 moves on to the next step, whose page stays a Help press away
        pts = app.resource(PackResource).pack.section("points")
        pending.extend([(0.2, PickPoint("skin", tuple(pts["landmark1_ideal_left"]["position"])))])
        app.run_steps(12)
        assert not h.doc_open and h.doc_name == "howto"
    finally:
        app.close()

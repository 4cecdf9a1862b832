"""The whole rhizotomy procedure done with the mouse only: face clicks, dial drags, slider clicks."""

from __future__ import annotations

from chainsim.components.input_events import MouseButton, MouseDrag, MouseMove
from chainsim.game.packbuild.needle.make_prp_mouse_script import SCRIPTS, build
from chainsim.game.trainer.headless import run_pack
from chainsim.game.trainer.inputscript import load_script

MOUSE = SCRIPTS / "correct-mouse.toml"


def test_shipped_mouse_script_is_up_to_date_with_the_layout_and_anatomy():
    assert MOUSE.read_text(encoding="utf-8") == build(SCRIPTS / "correct.toml")


def test_mouse_only_attempt_reaches_the_foramen():
    events = [e for _, e in load_script(MOUSE)]
    assert events and all(isinstance(e, (MouseButton, MouseDrag, MouseMove)) for e in events)
    s = run_pack("prp", 720, script=str(MOUSE))
    a = s["assessment"]
    assert a["target"] == "foramen_ovale_left"
    assert a["needle_error_mm"] < 1.0
    assert a["landmark_error_mm"] < 2.0
    assert a["skull_contacts"] == 0

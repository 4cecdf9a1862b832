"""In-app View of saved attempts (thesis Fig. 3.11): after Save, My attempts lists them in the panel."""

from __future__ import annotations

from chainsim.components.hud import HudState
from chainsim.components.input_events import Widget
from chainsim.components.resources import PendingInput
from chainsim.game.packbuild.needle.make_prp_mouse_script import SCRIPTS
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script


def test_saved_attempts_are_listed_for_the_trainee(tmp_path):
    db = tmp_path / "records.sqlite3"
    app = build_app("prp", settings={"db": str(db), "class": "c1", "trainee": "alice"})
    try:
        pending = app.resource(PendingInput)
        pending.extend([(0.1, Widget("my_attempts"))])
        app.run_steps(20)
        assert "No saved attempts yet for alice in class c1." in app.resource(HudState).panel_text
        events = load_script(SCRIPTS / "correct.toml")
        pending.extend([(t + 0.5, e) for t, e in events] + [(6.0, Widget("save")), (6.5, Widget("my_attempts"))])
        app.run_steps(int(7.0 * 120))
        text = app.resource(HudState).panel_text
        assert text[0] == "Attempts of alice (c1): 1"
        assert "reached foramen ovale left" in text[1]  # the target in words, not its id
    finally:
        app.close()

"""What the controller's panel and messages tell a trainee about their attempts: the self assessment
follows the attempt while it is shown (a bone hit's needle error appears), saved attempts are
numbered the same way in the save message and in My attempts (no record ids), and in a study the
save message does not send the participant to Reset."""

from __future__ import annotations

from pathlib import Path

from chainsim.components.hud import HudState
from chainsim.components.input_events import Widget
from chainsim.components.resources import PendingInput, Settings
from chainsim.game.trainer.headless import build_app
from chainsim.game.trainer.inputscript import load_script

PACK = Path(__file__).resolve().parents[2] / "assets" / "prp"


def play(app, events, seconds):
    t0 = app.time.sim_time
    app.resource(PendingInput).extend(sorted(((t0 + t, e) for t, e in events), key=lambda te: te[0]))
    for _ in range(int(seconds / app.time.dt)):
        app.update(app.time.dt)


def test_the_self_assessment_follows_a_bone_hit_while_shown(tmp_path):
    app = build_app(str(PACK), settings={"db": str(tmp_path / "r.sqlite3"), "class": "c1", "trainee": "ann"})
    try:
        events = load_script(PACK / "scripts" / "skull-hit.toml")
        last = max(t for t, _ in events)
        picks = [(t, e) for t, e in events if t < 2.0]
        play(app, [*picks, (1.9, Widget("self_assessment", None))], 2.0)
        h = app.resource(HudState)
        assert "needle error -" in h.panel_text[0]  # nothing touched yet
        play(app, [(t - 2.0, e) for t, e in events if t >= 2.0], last - 2.0 + 1.0)
        assert "needle error -" not in h.panel_text[0] and "needle error" in h.panel_text[0]
    finally:
        app.close()


def _save_two(app):
    events = load_script(PACK / "scripts" / "correct.toml")
    last = max(t for t, _ in events)
    play(app, [*events, (last + 0.1, Widget("save", None))], last + 0.5)
    play(app, [(0.01, Widget("reset", None)), (0.05, Widget("rotate_horizontal", 1.0))], 0.2)
    play(app, [(0.01, Widget("save", None))], 0.2)


def test_save_messages_and_my_attempts_number_attempts_alike(tmp_path):
    app = build_app(str(PACK), settings={"db": str(tmp_path / "r.sqlite3"), "class": "c1", "trainee": "ann"})
    h = app.resource(HudState)
    try:
        _save_two(app)
        said = [t for t, _ in h.messages]  # both still shown (messages last seconds)
        saves = [m for m in said if " saved for ann" in m]
        assert len(saves) == 2
        assert saves[0].startswith("Attempt 1 saved") and "number 1 in My attempts" in saves[0]
        assert saves[1].startswith("Attempt 2 saved") and "number 2 in My attempts" in saves[1]
        play(app, [(0.01, Widget("my_attempts", None))], 0.1)
        panel = h.panel_text
        assert panel[1].startswith("1. ") and panel[2].startswith("2. ") and "#" not in " ".join(panel)
        assert "reached foramen ovale left" in panel[1]
        assert "removes number 2, the newest" in panel[-1]
    finally:
        app.close()


def test_in_a_study_the_save_message_does_not_send_the_participant_to_reset(tmp_path):
    app = build_app(str(PACK), settings={"db": str(tmp_path / "r.sqlite3"), "class": "c1", "trainee": "ann"})
    h = app.resource(HudState)
    app.resource(Settings).values["protocol"] = {"study": "s", "participant": "ann", "trial": "t", "order": 1}
    try:
        events = load_script(PACK / "scripts" / "correct.toml")
        last = max(t for t, _ in events)
        play(app, [*events, (last + 0.1, Widget("save", None))], last + 0.5)
        saves = [t for t, _ in h.messages if " saved for ann" in t]
        assert saves and "Reset" not in saves[0]
    finally:
        app.close()

"""Headless runs: summary contents, determinism, recording and replay, input scripts."""

from __future__ import annotations

import json

import esper
import numpy as np
import pytest

from chainsim.components.core import Name, ScriptedMotion, Transform
from chainsim.components.input_events import Key, Widget
from chainsim.game.trainer.headless import build_app, run_pack
from chainsim.game.trainer.inputscript import load_script
from chainsim.systems.engine.errors import UserError


def test_run_writes_summary_with_steps_time_systems_digest(tmp_path):
    s = run_pack("loop-demo", 240, out=str(tmp_path))
    on_disk = json.loads((tmp_path / "summary.json").read_text())
    assert on_disk == json.loads(json.dumps(s))
    assert s["steps"] == 240
    assert s["simulated_time_s"] == pytest.approx(240 * s["dt"])
    assert "simulation/motion" in s["systems"]
    assert s["systems"]["simulation/motion"]["calls"] == 240
    assert len(s["digest"]) == 64


def test_same_script_same_digest_and_different_input_differs(tmp_path):
    a = run_pack("loop-demo", 300)
    b = run_pack("loop-demo", 300)
    assert a["digest"] == b["digest"]
    c = run_pack("loop-demo", 301)
    assert c["digest"] != a["digest"]


def test_motion_follows_simulated_time_not_wall_clock():
    app = build_app("loop-demo")
    try:
        app.run_steps(120)  # 1 s at 120 Hz; ball speed 120 mm/s from (60,0,20) toward (0,60,20)
        with app.active():
            ball = [e for e, n in esper.get_component(Name) if n.value == "ball"][0]
            pos = esper.component_for_entity(ball, Transform).position
        # 120 mm along the path (60,0)->(0,60)->(-60,0): past the first corner by 120 - |first leg|
        a, b, c = np.array([60.0, 0, 20]), np.array([0.0, 60, 20]), np.array([-60.0, 0, 20])
        rest = 120.0 - np.linalg.norm(b - a)
        expected = b + (c - b) / np.linalg.norm(c - b) * rest
        np.testing.assert_allclose(pos, expected, atol=1e-9)
    finally:
        app.close()


def test_record_then_replay_reaches_the_same_digest(tmp_path, cli):
    rec = tmp_path / "session.json"
    script = "assets/loop-demo/scripts/demo.toml"
    code, out, err = cli(
        "run", "loop-demo", "--headless", "--steps", "400", "--input", script, "--record", rec, "--out", tmp_path / "o"
    )
    assert code == 0, err
    data = json.loads(rec.read_text())
    assert data["chainsim"] == "recording" and len(data["event"]) == len(load_script(script))
    code, out, err = cli("replay", rec)
    assert code == 0, err
    assert "matches" in out
    data["digest"] = "0" * 64
    rec.write_text(json.dumps(data))
    code, out, err = cli("replay", rec)
    assert code == 1 and "DIFFERS" in out


def test_scene_selection_spawns_only_its_entities():
    app = build_app("loop-demo/still")
    try:
        with app.active():
            names = sorted(n.value for _, n in esper.get_component(Name))
            assert names == ["table"]
            assert esper.get_component(ScriptedMotion) == []
        # a scene with nothing moving gets no motion system: it pays for nothing it does not model
        assert "motion" not in app.systems("simulation")
    finally:
        app.close()


def test_input_script_events_are_released_at_their_time():
    from chainsim.systems.motion.input import InputLog

    app = build_app("loop-demo")
    try:
        from chainsim.components.resources import PendingInput

        app.resource(PendingInput).extend([(0.05, Key("a", True)), (0.10, Widget("x", 1.0))])
        app.run_steps(6)  # t = 0 .. 0.041: nothing yet
        assert app.resource(InputLog).items == []
        app.run_steps(1)  # frame starting at t = 0.05
        assert [type(e).__name__ for _, e in app.resource(InputLog).items] == ["Key"]
        app.run_steps(6)
        assert [type(e).__name__ for _, e in app.resource(InputLog).items] == ["Key", "Widget"]
    finally:
        app.close()


@pytest.mark.parametrize(
    "text,needle",
    [
        ("format = 2\n", "'format' must be 1"),
        ("format = 1\n[[event]]\nt = -1\nkind = 'key'\nkey = 'a'\n", "'t' must be"),
        ("format = 1\n[[event]]\nt = 1\nkind = 'teleport'\n", "unknown event kind"),
        ("format = 1\n[[event]]\nt = 1\nkind = 'mouse_move'\nx = nan\ny = 0\n", "'x' must be finite"),
        ("format = 1\n[[event]]\nt = 1\nkind = 'key'\n", "needs 'key'"),
        (
            "format = 1\n[[event]]\nt = 2\nkind = 'key'\nkey = 'a'\n[[event]]\nt = 1\nkind = 'key'\nkey = 'b'\n",
            "time order",
        ),
        ("format = 1\n[[event]]\nt = 1\nkind = 'mouse_button'\nx = 1\ny = 1\nbutton = 'fourth'\n", "'button' must be"),
        ("format = 1\n[[event]]\nt = 1\nkind = 'key'\nkey = 'a'\ncolour = 3\n", "unknown key(s) colour"),
        ("format = 1\nevent = [\n", "TOML syntax error"),
    ],
)
def test_bad_input_scripts_give_one_clear_line(tmp_path, text, needle):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(UserError) as e:
        load_script(p)
    assert needle in str(e.value)
    assert "\n" not in str(e.value)

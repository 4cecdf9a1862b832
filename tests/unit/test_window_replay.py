"""A window session replays to the same digest whatever its frame times: the window runs whole fixed
steps (chainsim.game.trainer.frameloop), and `chainsim replay` runs the recording one step per update."""

from __future__ import annotations

import numpy as np

from chainsim.components.digest import world_digest
from chainsim.components.input_events import MouseButton, Widget
from chainsim.components.resources import PendingInput
from chainsim.game.packbuild.needle.make_prp_mouse_script import SCRIPTS
from chainsim.game.trainer.frameloop import FixedStepper
from chainsim.game.trainer.headless import build_app, run_pack
from chainsim.game.trainer.inputscript import load_script
from chainsim.systems.motion.input import InputLog


def window_session(frame_times):
    """Drive the App as the window does: events arrive between frames, stamped with the current
    simulated time, and each frame advances by its wall time in whole steps."""
    app = build_app("prp")
    try:
        stepper = FixedStepper(app)
        pending = app.resource(PendingInput)
        script = load_script(SCRIPTS / "correct-mouse.toml")
        k = 0
        for wall_dt in frame_times:
            # the trainee's input reaches the window at its script time (plus whatever the frame took)
            while k < len(script) and script[k][0] <= app.time.sim_time:
                pending.push(app.time.sim_time, script[k][1])
                k += 1
            stepper.advance(wall_dt)
        pending.push(app.time.sim_time, Widget("self_assessment"))
        stepper.advance(0.05)
        log = app.resource(InputLog).items
        return app.time.tick, list(log), world_digest(app), app.time.dt
    finally:
        app.close()


def test_uneven_frames_replay_to_the_same_digest():
    rng = np.random.default_rng(7)
    # 4 ms to 120 ms frames, with stalls, about 7 simulated seconds
    uneven = list(rng.choice([0.004, 0.009, 0.016, 0.033, 0.05, 0.12], size=260))
    ticks, events, digest, dt = window_session(uneven)
    assert any(isinstance(e, MouseButton) for _, e in events)
    replay = run_pack("prp", ticks, events=events, dt=dt)
    assert replay["digest"] == digest
    assert replay["assessment"]["target"].startswith("foramen_ovale")

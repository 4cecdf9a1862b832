"""A device on a running needle pack: `chainsim run PACK --device sim` drives the needle from the servo's tool,
writes the forces, records what a replay needs and compiles nothing mid-run; bad devices are one line; a
driver's port is read and written along its axis, with the clutch."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from chainsim.game.cli.main import main
from chainsim.systems.engine import quaternion as Q
from chainsim.systems.engine.haptics import model as M
from chainsim.systems.engine.haptics import port as P
from chainsim.systems.engine.haptics import servo as S
from chainsim.systems.engine.haptics import simdevice as D

REPO = Path(__file__).resolve().parents[2]
#: prp's correct script up to the needle's aim (its landmarks, then the dials), without its insertion
AIM_UNTIL = 4.0


@pytest.fixture(scope="module")
def aim_script(tmp_path_factory) -> Path:
    import tomllib

    import tomli_w

    script = tomllib.loads((REPO / "assets/prp/scripts/correct.toml").read_text())
    script["event"] = [e for e in script["event"] if e["t"] < AIM_UNTIL and e.get("name") != "insert"]
    path = tmp_path_factory.mktemp("aim") / "aim.toml"
    path.write_text(tomli_w.dumps(script))
    return path


def _run(*args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "chainsim.game.cli.main", *args], capture_output=True, text=True)


def test_a_run_with_the_simulated_device_punctures_writes_the_forces_and_replays_without_it(aim_script, tmp_path):
    keys = tmp_path / "keys.csv"  # placed at ~1.5 s and aimed by 2.5 s: wait, then in to 25 mm and hold
    keys.write_text("t_s,depth_mm\n0,-3\n2.5,-3\n7,25\n")
    out, rec = tmp_path / "out", tmp_path / "rec.json"
    steps = 1000  # 8.3 s
    args = ["run", "prp", "--device", f"sim:{keys}", "--input", str(aim_script), "--steps", str(steps)]
    res = _run(*args, "--out", str(out), "--record", str(rec), "--json")
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    trace = (out / "needle_trace.csv").read_text()
    assert "puncture:skin" in trace and "puncture:muscle" in trace  # the device's push went through the layers
    rows = np.genfromtxt(out / "haptic_trace.csv", delimiter=",", names=True)
    assert len(rows) == round((summary["simulated_time_s"] - summary["dt"]) * 1000)  # every tick to the last step
    assert rows["force_N"].max() > 1.0 and rows["passed"].max() >= 3
    # the needle behind the hand by the tissue's drag through the coupling, the hand behind its path likewise
    assert 20.0 < rows["tool_mm"].max() < rows["hand_mm"].max() < rows["ref_mm"].max() <= 25.0
    # the attempt's force figures: the skin gave at its puncture force, felt through the coupling
    a = summary["assessment"]
    assert a["device"] == f"sim:{keys}" and a["puncture_force_N"] == pytest.approx(1.22, abs=0.05)
    assert a["device_peak_force_N"] == pytest.approx(rows["force_N"].max(), abs=1e-5) and a["bone_contact_s"] == 0.0
    assert 100 < len(a["force_profile"]) <= 450 and (out / "haptic_force.png").stat().st_size > 10_000
    # the recording holds the depths the device gave: a replay without the device reaches the same world
    again = _run("replay", str(rec))
    assert again.returncode == 0, again.stderr
    assert "matches the recording" in again.stdout
    # and the same run again gives the same forces
    res2 = _run(*args, "--out", str(tmp_path / "out2"), "--json")
    assert (tmp_path / "out2" / "haptic_trace.csv").read_bytes() == (out / "haptic_trace.csv").read_bytes()
    assert json.loads(res2.stdout)["digest"] == summary["digest"]


def test_pushed_on_to_the_target_the_needle_stops_there_and_the_time_held_is_counted(aim_script, tmp_path):
    keys = tmp_path / "keys.csv"  # in past the foramen (67 mm along the path) and held
    keys.write_text("t_s,depth_mm\n0,-3\n2.5,-3\n9.5,75\n")
    res = _run("run", "prp", "--device", f"sim:{keys}", "--input", str(aim_script), "--steps", "1500", "--json")
    assert res.returncode == 0, res.stderr
    a = json.loads(res.stdout)["assessment"]
    assert a["target_reached"] and a["target"] != "none"
    assert 0.3 < a["bone_contact_s"] < 12.5 - 9.5 + 1.0  # held at the target from reaching it to the end
    assert a["device_peak_force_N"] > 2.0  # the hand, pushing on, feels the wall say so


def test_packs_metrics_can_name_the_force_measures():
    from chainsim.systems.procedures.needle.assessment import metric_values

    class Pack:
        def section(self, name):
            return {"pop_N": {"measure": "puncture_force"}, "on_bone_s": {"measure": "bone_contact_time"},
                    "felt_N": {"measure": "device_peak_force"}}  # fmt: skip

    v = {"puncture_force_N": 1.2, "bone_contact_s": 0.5, "device_peak_force_N": 2.5}
    assert metric_values(Pack(), None, v) == {"pop_N": 1.2, "on_bone_s": 0.5, "felt_N": 2.5}
    assert metric_values(Pack(), None, {}) == {"pop_N": None, "on_bone_s": None, "felt_N": None}  # no device


def _signatures() -> dict:
    from chainsim.systems.engine.haptics import clock, model

    out = {}
    for mod in (clock, model, D, S):
        for name, v in vars(mod).items():
            if hasattr(v, "signatures") and getattr(v, "py_func", v).__module__ == mod.__name__:
                out[f"{mod.__name__}.{name}"] = set(map(str, v.signatures))
    return out


def test_a_device_run_compiles_nothing_warmup_left_out(aim_script):
    from chainsim.systems.engine.warmup import GROUPS, HAPTICS

    GROUPS[HAPTICS]()
    before = _signatures()
    main(["-q", "run", "prp", "--device", "sim", "--input", str(aim_script), "--steps", "700"])
    after = _signatures()
    assert {k: v - before.get(k, set()) for k, v in after.items() if v - before.get(k, set())} == {}


@pytest.mark.parametrize(
    "device, said",
    [
        ("phantom9", "unknown device 'phantom9'; known: sim, touch"),
        ("touch", "needs the Python package pyOpenHaptics"),
        ("sim:/nonexistent/keys.csv", "cannot read it"),
    ],
)
def test_a_device_that_cannot_be_had_is_one_line_and_exit_2(device, said):
    if device == "touch":  # the message is for a machine without the package
        import importlib.util

        if importlib.util.find_spec("pyOpenHaptics") is not None:
            pytest.skip("pyOpenHaptics is installed here")
    res = _run("run", "prp", "--device", device, "--steps", "1")
    assert res.returncode == 2
    assert said in res.stderr and len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr


class FakePort:
    """A device at a position the test sets, recording the forces written to it."""

    name, max_force_N = "fake", 3.3
    axis = np.array([0.0, 0.0, -1.0])

    def __init__(self):
        self.position, self.buttons, self.forces = np.zeros(3), 0, []

    def clock(self) -> float:
        return 0.0

    def read(self) -> P.DeviceSample:
        return P.DeviceSample(self.position.copy(), np.array([1.0, 0.0, 0.0, 0.0]), self.buttons)

    def write(self, force_N) -> None:
        self.forces.append(np.array(force_N))

    def close(self) -> None:
        pass


def test_a_port_device_is_read_along_its_axis_pushed_back_along_it_and_clutched():
    wall = M.new_model()
    wall[M.M_PLACED], wall[M.M_GEN], wall[M.M_WALL] = 1.0, 1.0, 5.0
    dev = FakePort()
    servo = S.Servo(M.new_cfg(), np.zeros(1), D.new_hand(0.0), mode="python", port=dev)
    servo.refresh(wall)
    dev.position[:] = (3.0, 4.0, 20.0)  # where the hand is when the needle is placed: depth 0
    servo._port_tick()
    for z in np.linspace(20.0, 12.0, 9):  # pushed 8 mm along -Z: 3 mm past the wall at 5 mm
        dev.position[2] = z
        servo._port_tick()
    assert servo.state[M.S_XT] == 5.0
    f = dev.forces[-1]
    assert f[0] == f[1] == 0.0 and f[2] > 1.0  # pushed back towards the hand (+Z), by the coupling
    dev.buttons = 1  # clutch: the hand goes back without the needle
    for z in np.linspace(12.0, 30.0, 10):
        dev.position[2] = z
        servo._port_tick()
    dev.buttons = 0
    servo._port_tick()
    assert servo.log[servo.ticks - 1, D.L_HAND] == pytest.approx(8.0)  # still where it was held
    servo.stop()
    assert not dev.forces[-1].any()  # a stopped servo leaves the device with no force


class StylusPort(FakePort):
    """A fake device whose stylus the test also turns (orientation w, x, y, z in the device's frame)."""

    name = "stylus"
    up = np.array([0.0, 1.0, 0.0])

    def __init__(self):
        super().__init__()
        self.orientation = np.array([1.0, 0.0, 0.0, 0.0])

    def read(self) -> P.DeviceSample:
        return P.DeviceSample(self.position.copy(), self.orientation.copy(), self.buttons)


def _turned(axis, deg) -> np.ndarray:
    return Q.from_axis_angle(axis, np.radians(deg))


def test_the_stylus_aims_the_needle_outside_tissue_and_tissue_holds_the_hand_on_the_line(aim_script, monkeypatch):
    """A real device's stylus turns the needle's dials while the needle is out of the tissue; once in, turning it
    asks for nothing (no refused turn is counted) and moving the hand across the needle's line is pushed back."""
    import time

    import esper

    from chainsim.components.resources import PendingInput
    from chainsim.game.trainer.headless import build_app
    from chainsim.game.trainer.inputscript import load_script
    from chainsim.systems.procedures.needle import haptics as H
    from chainsim.systems.procedures.needle.components import NeedleState

    dev = StylusPort()
    monkeypatch.setitem(P.DRIVERS, "stylus", P.Driver("numpy", "x:y", "a test stylus"))
    monkeypatch.setattr(P, "open_device", lambda spec: dev)
    app = build_app("prp")
    try:
        app.resource(PendingInput).extend(load_script(aim_script))
        app.run_steps(int(AIM_UNTIL * 120))
        link = H.attach(app, "stylus", realtime=True)
        with app.active():  # the same object all along: the systems change it in place
            st = esper.component_for_entity(app.resource(H.NeedleHandles).needle, NeedleState)

        def steps(n=6):
            for _ in range(n):
                seen = link.servo.ticks  # the servo's thread has read the stylus as it is now: two ticks on
                deadline = time.monotonic() + 10.0
                while link.servo.ticks < seen + 2 and time.monotonic() < deadline:
                    time.sleep(0.001)
                app.update(app.time.dt)

        assert st.placed and not st.locked
        steps()
        yaw0, pitch0 = st.yaw, st.pitch
        dev.orientation = _turned(dev.up, 10.0)  # turned left about the device's up: the needle turns with it
        steps()
        assert st.yaw == pytest.approx(yaw0 + 10.0, abs=0.01) and st.pitch == pytest.approx(pitch0, abs=0.01)
        heading = Q.rotate(_turned(dev.up, 10.0), dev.axis)
        dev.orientation = Q.mul(_turned(np.cross(heading, dev.up), 4.0), _turned(dev.up, 10.0))  # then tip raised 4
        steps()
        assert st.pitch == pytest.approx(pitch0 + 4.0, abs=0.05) and st.yaw == pytest.approx(yaw0 + 10.0, abs=0.05)
        assert not any(f[:2].any() for f in dev.forces)  # out of tissue: no force across the axis
        # pushed in along the device's axis (-Z) until the skin gives and the needle is 8 mm in
        for z in np.linspace(0.0, -14.0, 60):
            dev.position[2] = z
            steps(1)
        steps(30)
        assert st.locked and st.depth > 5.0 and link.servo.embedded() > 3.0
        yaw_in, refused = st.yaw, st.rotation_refused
        dev.orientation = _turned(dev.up, 30.0)  # turned hard in tissue: nothing asked, nothing refused
        steps()
        assert st.yaw == yaw_in and st.rotation_refused == refused
        # the hand moved 3 mm across the line (+X): pushed back (-X), more firmly the deeper the needle
        dev.position[0] = 3.0
        steps(10)
        f = dev.forces[-1]
        assert f[0] < -0.1 and abs(f[1]) < 1e-9
        link.servo.stop()
    finally:
        app.close()


def test_tissue_holds_the_needle_on_its_line_from_where_it_went_in_stiffer_the_deeper():
    lat = P.Lateral(np.array([0.0, 0.0, -1.0]), 1e-3, 6e-4)
    ref = np.zeros(3)
    assert not lat(np.array([2.0, 0.0, -3.0]), ref, 0.0).any()  # not in tissue: the hand moves freely
    assert not lat(np.array([2.0, 0.0, -3.0]), ref, 0.1).any()  # the line is where the hand went in: no step
    forces = []
    for depth in (5.0, 10.0, 20.0, 30.0, 60.0):
        lat(np.array([2.0, 0.0, -3.0]), ref, depth)  # held still across the line (no speed)
        forces.append(lat(np.array([3.0, 0.0, -9.0]), ref, depth))  # 1 mm across, any depth along the axis
        lat(np.array([2.0, 0.0, -3.0]), ref, depth)
    assert all(f[1] == 0.0 and f[2] == 0.0 and f[0] < 0.0 for f in forces)  # back across, never along the axis
    spring = [-(f[0] + 6e-4 * 1.0 / 1e-3) for f in forces]  # less the damper's share (1 mm in one tick)
    assert spring == pytest.approx([0.1, 0.2, 0.4, 0.6, 0.6])  # 0.02 N/mm per mm in, at most 0.6 N/mm

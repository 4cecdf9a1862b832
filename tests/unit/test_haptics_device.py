"""The simulated device against the local contact model, as CI checks the haptics: a puncture is felt as a
drop in the tick it happens, the force is otherwise continuous, a bone wall gives back no energy it was not
given, and one trajectory gives one force log, byte for byte."""

from __future__ import annotations

import hashlib
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from chainsim.systems.engine.haptics import model as M
from chainsim.systems.engine.haptics import simdevice as D
from chainsim.systems.engine.needle_force import punch_stiffness

REPO = Path(__file__).resolve().parents[2]
#: the largest step in force between two ticks outside a puncture (docs/haptics.md, "Continuity")
CONTINUITY_N = 0.05
#: layer thicknesses along prp's path (docs/tissue-layers.md); the deep layer runs on to bone
THICKNESS = {"skin": 1.8, "subcutaneous": 6.0, "muscle": 8.0}


def prp_line(bone: float = 40.0) -> np.ndarray:
    """A model of prp's tissue along a straight line from the skin to bone `bone` mm deep, from the pack's data."""
    pack = tomllib.loads((REPO / "assets/prp/pack.toml").read_text())
    radius = pack["needle_tissue"]["contact_radius_mm"]
    rows, depth = [], 0.0
    for name, L in sorted(pack["tissue_layers"].items(), key=lambda kv: kv[1]["mesh_layer"]):
        k = punch_stiffness(L["E_kPa"], L["nu"], radius)
        rows.append(
            (depth, bone - depth, k, L["puncture_N"], L["cutting_N"], L["friction_static_N_per_mm"],
             L["friction_dynamic_N_per_mm"], L["friction_viscous_Ns_per_mm2"], 0.0)
        )  # fmt: skip
        depth += THICKNESS.get(name, 0.0)
    model = M.new_model()
    M.set_crossings(model, rows)
    model[M.M_PLACED], model[M.M_GEN], model[M.M_WALL] = 1.0, 1.0, bone
    return model


def frames(model: np.ndarray, ticks: int) -> tuple[np.ndarray, np.ndarray]:
    """The same model refreshed as a 60 Hz simulation would: every 1000/60 ticks."""
    at = np.floor(np.arange(0, ticks, 1000 / 60)).astype(np.int64)
    return np.repeat(model[None], len(at), axis=0), at


def transients(log: np.ndarray) -> np.ndarray:
    """Ticks belonging to a puncture: the tick the boundary gives and those after it while the needle, which
    lurched forward, still runs ahead of the hand."""
    ev = log[:, D.L_EVENT].astype(int)
    ahead = np.diff(log[:, D.L_TOOL]) > np.diff(log[:, D.L_HAND]) + 1e-3  # more than 1 mm/s faster
    out = np.zeros(len(log), bool)
    for k in np.nonzero(ev & M.EV_PUNCTURE)[0]:
        j = k
        while j < len(log) and (j == k or ahead[j - 1]):
            out[j] = True
            j += 1
    return out


@pytest.mark.parametrize("speed", [5.0, 10.0, 25.0])
def test_puncture_is_a_drop_within_one_tick_and_the_force_is_continuous_otherwise(speed):
    model = prp_line()
    traj = D.scripted(D.insertion(45.0, speed))  # on into bone, held, withdrawn
    log = D.run(M.new_cfg(), *frames(model, len(traj)), traj)
    f, ev = log[:, D.L_FORCE], log[:, D.L_EVENT].astype(int)
    punctures = np.nonzero(ev & M.EV_PUNCTURE)[0]
    # every layer gave way (two in one tick where the skin gives deeper than the next boundary), then out again
    assert log[:, D.L_PASSED].max() == 4 and len(punctures) >= 3 and log[-1, D.L_PASSED] == 0
    for k in punctures:  # the tick the boundary gives is the tick the hand feels it
        assert f[k] < f[k - 1] - CONTINUITY_N
    steps = np.abs(np.diff(f))[~transients(log)[1:]]
    assert steps.max() <= CONTINUITY_N
    assert log[:, D.L_WALL].any() and log[:, D.L_TOOL].max() == 40.0  # met the bone, never passed it


@pytest.mark.parametrize("tissue", [False, True])
@pytest.mark.parametrize("speed", [10.0, 60.0])
def test_a_bone_wall_gives_back_no_energy_over_a_push_and_hold(tissue, speed):
    bone = 20.0
    model = prp_line(bone) if tissue else M.new_model()
    model[M.M_PLACED], model[M.M_GEN], model[M.M_WALL] = 1.0, 1.0, bone
    # pushed 6 mm past the bone, held two seconds, let go back to the start
    traj = D.scripted([(0.0, -3.0), (0.5, -3.0), (0.5 + 29.0 / speed * 1.875, 26.0), (2.5 + 29.0 / speed * 1.875,
                       26.0), (3.5 + 29.0 / speed * 1.875, -3.0), (4.5 + 29.0 / speed * 1.875, -3.0)])  # fmt: skip
    log = D.run(M.new_cfg(), *frames(model, len(traj)), traj)
    held = log[:, D.L_WALL] == 1.0
    assert held.sum() > 2000 and log[:, D.L_TOOL].max() == bone
    # energy the device gives the hand: the force held over each tick times how far the hand moved in it
    given = np.cumsum(-log[:-1, D.L_FORCE] * np.diff(log[:, D.L_HAND]))
    assert given.max() <= 1e-9  # N mm: never more out than went in, at any moment


def _digest() -> str:
    model = prp_line()
    traj = D.scripted(D.insertion(45.0, 10.0))
    return hashlib.sha256(D.run(M.new_cfg(), *frames(model, len(traj)), traj).tobytes()).hexdigest()


def test_the_same_trajectory_gives_the_same_force_log_byte_for_byte():
    here = _digest()
    assert here == _digest()
    code = "import sys; sys.path.insert(0, 'tests/unit'); import test_haptics_device as t; print(t._digest())"
    other = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert other.stdout.strip() == here


def test_a_trajectory_file_is_keyframes_or_a_recorded_trace(tmp_path):
    keys = tmp_path / "keys.csv"
    keys.write_text("t_s,depth_mm\n0,-3\n1,7\n")
    traj = D.load(str(keys))
    assert len(traj) == 1001 and traj[0] == -3.0 and traj[-1] == 7.0
    assert np.all(np.diff(traj) >= 0) and np.diff(traj)[[0, -1]].max() < 1e-4  # starts and ends at rest
    trace = tmp_path / "trace.csv"
    trace.write_text("time_s,hand_mm,tool_mm,force_N\n0,1.5,1.5,0\n0.001,1.6,1.6,0\n")
    assert D.load(str(trace)).tolist() == [1.5, 1.6]
    bad = tmp_path / "bad.csv"
    bad.write_text("when,where\n0,1\n")
    with pytest.raises(ValueError, match="expected columns t_s,depth_mm"):
        D.load(str(bad))

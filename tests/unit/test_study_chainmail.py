"""ChainMail in the study at the material extremes, and the study's metrics and presets."""

import numpy as np
import pytest

from chainsim.systems.engine.errors import UserError
from chainsim.tools.study import calibrate as cal
from chainsim.tools.study.chainmail_model import ChainMailModel, ChainMailParams
from chainsim.tools.study.metrics import displacement_error, pareto_front, realtime_size, volume_change
from chainsim.tools.study.scenes import block, sheet


@pytest.mark.parametrize(
    "params",
    [
        ChainMailParams(1.0, 1.0, 0.0, 0),  # rigid
        ChainMailParams(0.999, 1.001, 0.0005, 8),  # near-rigid (bone-like)
        ChainMailParams(0.01, 100.0, 10.0, 32),  # extremely soft
        ChainMailParams(0.5, 2.5, 0.3, 64),
    ],
)
@pytest.mark.parametrize("strain", [1e-6, 0.5, 20.0])
def test_chainmail_stays_finite_at_the_extremes(params, strain):
    s = block(5)
    cm = ChainMailModel(s.pos, s.links, s.fixed)
    u, info = cm.solve(s.grabbed, s.grab_disp(strain), params)
    assert np.all(np.isfinite(u))
    np.testing.assert_allclose(u[s.grabbed, 2], strain)
    assert np.all(u[s.fixed] == 0)
    assert info["moved"] >= len(s.grabbed)


def test_softer_chainmail_moves_fewer_elements():
    s = sheet(12)
    cm = ChainMailModel(s.pos, s.links, s.fixed)
    moved = [
        cm.solve(s.grabbed, s.grab_disp(0.2), ChainMailParams(1 - g, 1 + g, g / 2))[1]["moved"]
        for g in (0.01, 0.2, 1.0)
    ]
    assert moved[0] > moved[1] > moved[2]


def test_metrics():
    u_ref = np.zeros((4, 3))
    u = np.array([[0, 0, 0.1], [0, 0, 0], [0, 0, 0], [0, 0, 0]])
    rms, mx = displacement_error(u, u_ref, 0.1)
    assert np.isclose(mx, 1.0) and np.isclose(rms, 0.5)
    s = block(3)
    vc = volume_change(s.pos, s.tets, 0.1 * s.pos)  # uniform 10 % dilation
    assert np.isclose(vc["volume_change"], 1.1**3 - 1) and vc["inverted_fraction"] == 0
    assert pareto_front([(1, 5), (2, 3), (3, 4), (4, 1)]) == [0, 1, 3]
    ns = np.array([1e3, 1e4, 1e5])
    assert np.isclose(realtime_size(ns, 1e-6 * ns, 30.0), 1 / 30 / 1e-6)


def test_presets_round_trip_and_keep_other_tables(tmp_path):
    path = tmp_path / "materials.toml"
    base = {
        "alpha_min": 0.9,
        "alpha_max": 1.1,
        "beta": 0.05,
        "relax_iterations": 8,
        "fitted_error": 0.07,
        "source": 'test "quoted"',
        "nu": 0.45,
        "E": 3000.0,
        "strain": 0.1,
    }
    cal.write_preset("soft", base, path)
    cal.write_preset("hard", base | {"alpha_max": 1.01}, path)
    got = cal.load_presets(path)
    assert set(got) == {"soft", "hard"}
    assert got["soft"]["alpha_max"] == 1.1 and got["hard"]["alpha_max"] == 1.01
    assert got["soft"]["source"] == 'test "quoted"'
    with pytest.raises(UserError):
        cal.write_preset("bad name!", base, path)
    assert set(cal.load_presets(path)) == {"soft", "hard"}  # nothing lost


def test_strain_level_follows_modulus_and_is_bounded():
    assert cal.strain_for(3000.0) == pytest.approx(cal.REFERENCE_TRACTION / 3000.0)
    assert cal.strain_for(1e12) == cal.MIN_STRAIN
    assert cal.strain_for(1.0) == cal.MAX_STRAIN
    with pytest.raises(UserError):
        cal.strain_for(None, 2.0)


def test_shipped_presets_file_is_complete():
    presets = cal.load_presets()
    for name, _E, _nu in cal.SHIPPED:
        p = presets[name]
        for key in cal.FIELDS:
            assert key in p
        assert 0 < p["alpha_min"] <= 1 <= p["alpha_max"] and p["beta"] >= 0
        assert p["fitted_error"] < 0.2

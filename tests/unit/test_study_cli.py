"""`chainsim study`: bad input is one line and exit code 2; calibrate writes a usable preset."""

import tomllib

from chainsim.game.cli.main import main


def test_bad_poisson_ratio_is_rejected_with_exit_code_2(tmp_path, capsys):
    out = tmp_path / "m.toml"
    code = main(["study", "calibrate", "--nu", "0.7", "--name", "x", "--out", str(out)])
    assert code == 2
    err = capsys.readouterr().err
    assert "Poisson" in err and "Traceback" not in err
    assert not out.exists()


def test_unknown_scene_is_rejected(tmp_path, capsys):
    code = main(["study", "speed-accuracy", "--quick", "--scenes", "blob", "--out", str(tmp_path)])
    assert code == 2
    assert "blob" in capsys.readouterr().err


def test_calibrate_writes_named_preset(tmp_path):
    out = tmp_path / "materials.toml"
    out.write_text(
        "[keep]\nalpha_min = 0.5\nalpha_max = 2.0\nbeta = 0.1\nrelax_iterations = 0\n"
        'fitted_error = 0.3\nsource = "hand"\n',
        encoding="utf-8",
    )
    assert main(["study", "calibrate", "--nu", "0.3", "--strain", "0.05", "--name", "t", "--out", str(out)]) == 0
    data = tomllib.loads(out.read_text(encoding="utf-8"))
    assert set(data) == {"keep", "t"}
    t = data["t"]
    assert 0 < t["alpha_min"] <= 1 <= t["alpha_max"] and t["strain"] == 0.05
    assert 0 <= t["fitted_error"] < 0.3

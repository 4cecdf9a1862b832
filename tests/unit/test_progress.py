"""Long jobs show one progress bar that ends its line; -q silences it."""

from __future__ import annotations

from chainsim.game.cli.main import main


def test_a_long_headless_run_shows_a_finished_bar_and_q_silences_it(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("CHAINSIM_PROGRESS", raising=False)
    assert main(["run", "loop-demo", "--headless", "--steps", "2000", "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert "steps: 100%" in err and "2000/2000" in err
    assert err.split("2000/2000", 1)[1].split("\n", 1)[0].count("\r") == 0  # the bar's last state ends its line
    assert main(["-q", "run", "loop-demo", "--headless", "--steps", "2000", "--out", str(tmp_path / "b")]) == 0
    assert "steps" not in capsys.readouterr().err

"""CLI edges a user meets: no display, bad flags, help; one line and exit 2, never a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_play_without_a_display_points_to_the_headless_command(cli, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    code, out, err = cli("play", "loop-demo")
    assert code == 2
    assert "no display" in err and "chainsim run loop-demo --headless" in err
    assert err.count("\n") == 1


def test_bad_flag_values_are_one_line_exit_2(cli):
    for args, words in (
        (("run", "loop-demo", "--steps", "-5"), "must be from 0 to"),
        (("run", "loop-demo", "--size", "big"), "WIDTHxHEIGHT"),
        (("run", "loop-demo", "--dt", "nan"), "argument --dt: expected a finite number"),
    ):
        code, out, err = cli(*args)
        assert code == 2, args
        assert words in err, (args, err)


def test_missing_input_script_is_one_line(cli, tmp_path):
    code, out, err = cli("run", "loop-demo", "--input", tmp_path / "nope.toml", "--out", tmp_path / "o")
    assert code == 2 and "input file not found" in err
    assert not (tmp_path / "o" / "summary.json").exists()


def test_python_dash_m_game_is_the_chainsim_command():
    r = subprocess.run([sys.executable, "-m", "game", "--help"], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0
    for cmd in (
        "run",
        "validate",
        "packs",
        "play",
        "replay",
        "docs",
        "chainmail",
        "bench",
        "records",
        "snapshot",
        "study",
        "protocol",
    ):
        assert cmd in r.stdout, cmd


def test_top_level_help_says_what_protocol_and_warmup_do():
    r = subprocess.run(
        [sys.executable, "-m", "chainsim.game.cli.main", "--help"], capture_output=True, text=True, cwd=ROOT
    )
    assert r.returncode == 0, r.stderr
    text = " ".join(r.stdout.split())  # argparse wraps the help column
    assert "run a study protocol with a participant at the window (or --scripted)" in text
    assert "scripted trials" not in text
    assert "compile every numba kernel a built-in pack can reach now (a minute or two" in text
    assert "(seconds," not in text


def test_top_level_help_is_each_commands_own_help():
    # the table in main.py stands in for the modules so `--help` stays light; it must not drift from them
    from chainsim.game.cli.main import COMMANDS, command_module

    assert {name: command_module(name).HELP for name in COMMANDS} == COMMANDS

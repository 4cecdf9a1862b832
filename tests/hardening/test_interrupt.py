"""Ctrl-C during a long headless run: one line naming the step it stopped at and what it wrote, exit
130, and what it wrote kept (the summary of the steps run, the procedure's files, a replayable recording)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time

from .conftest import ROOT, chainsim

#: tqdm's count once a step has run ("  12/100000 [")
STEPPING = re.compile(rb"\b[1-9][0-9]*/100000\b")


def _from_a_terminal() -> None:
    """In the child, before it runs: Ctrl-C's signal as a terminal hands it over. A shell starts background
    jobs with SIGINT ignored, and a test suite started that way (nohup, &) would pass the child that."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def interrupt_when_stepping(*args: str, timeout: float = 600) -> tuple[int, str]:
    """Start `chainsim ARGS`, send SIGINT once its progress bar shows a step done; (exit code, stderr)."""
    env = {**os.environ, "PYGLET_HEADLESS": "true", "MPLBACKEND": "Agg", "CHAINSIM_PROGRESS": "1"}
    env.pop("CHAINSIM_PACK_PATH", None)
    proc = subprocess.Popen(
        [sys.executable, "-m", "chainsim.game.cli.main", *args],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
        cwd=ROOT,
        preexec_fn=_from_a_terminal,
    )
    err, stepping = bytearray(), threading.Event()

    def read() -> None:  # the bar rewrites its line with \r: read what comes, not lines
        while chunk := os.read(proc.stderr.fileno(), 4096):
            err.extend(chunk)
            if STEPPING.search(err):
                stepping.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        assert stepping.wait(timeout), f"never started stepping: {bytes(err)[-2000:]!r}"
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(10)
    return code, err.decode()


def said(err: str) -> list[str]:
    """stderr without the progress bar's lines."""
    return [line for line in re.split(r"[\r\n]", err) if line.strip() and not line.startswith("steps:")]


def test_ctrl_c_in_a_long_needle_run_is_one_line_exit_130_and_keeps_what_it_wrote(tmp_path):
    out = tmp_path / "out"
    db = tmp_path / "r.sqlite3"
    code, err = interrupt_when_stepping("run", "prp", "--steps", "100000", "--out", out, "--db", db)
    assert code == 130, err[-2000:]
    assert "Traceback" not in err
    last = said(err)[-1]
    m = re.fullmatch(r"chainsim run: interrupted at step (\d+) of 100000; wrote (.*)", last)
    assert m, last
    assert m.group(2) == f"{out / 'summary.json'}, {out / 'needle_trace.csv'}"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["steps"] == int(m.group(1)) >= 1
    assert summary["interrupted"] == {"steps_run": summary["steps"], "steps_asked": 100000}
    trace = (out / "needle_trace.csv").read_text().splitlines()
    assert trace and trace[0]  # the procedure's file, as a whole run writes it


def test_an_interrupted_recording_replays_to_the_digest_it_stopped_at(tmp_path):
    rec = tmp_path / "r.json"
    code, err = interrupt_when_stepping("run", "loop-demo", "--steps", "100000", "--record", rec)
    assert code == 130 and "Traceback" not in err, err[-2000:]
    steps = int(re.search(r"interrupted at step (\d+) of 100000; wrote (\S+)$", said(err)[-1]).group(1))
    recording = json.loads(rec.read_text())
    assert recording["steps"] == steps
    r = chainsim("replay", rec)
    assert r.returncode == 0, r.stderr
    assert recording["digest"][:16] in r.stdout


def test_ctrl_c_while_the_command_loads_is_one_line():
    # sent as the command's modules load (numba, numpy) or, on a fast machine, as the pack builds
    env = {**os.environ, "PYGLET_HEADLESS": "true", "MPLBACKEND": "Agg"}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, chainsim.game.cli.main as m; print('ready', flush=True); sys.exit(m.main())",
            "run",
            "prp",
            "--steps",
            "1",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        cwd=ROOT,
        preexec_fn=_from_a_terminal,
    )
    assert proc.stdout.readline() == "ready\n"
    time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=600)  # a loaded CI machine starts slowly
    assert proc.returncode == 130, err[-2000:]
    assert "Traceback" not in err and err.strip().splitlines()[-1].startswith("chainsim")

"""Replay processes are killable and die with the server (chainsim.game.server.replayer).

A replay past its budget is killed, and the budget the replay reports once it has read its
recording replaces the first one; a cancelled replay is killed; a crashed process is replaced on
the next job; and a server killed with SIGKILL or SIGTERM leaves no replay process behind.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from chainsim.game.server.replayer import Cancelled, OverBudget, ReplayFailed, ReplayProcess

TESTS = Path(__file__).resolve().parents[1]


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as fh:  # a zombie is gone in all but name
        return fh.read().split(")")[-1].split()[0] != "Z"


@pytest.fixture
def proc():
    p = ReplayProcess("replay_targets:sleepy")
    yield p
    p.close()


def test_a_replay_past_its_budget_is_killed_and_the_next_job_runs(proc):
    assert proc.run((0.0,), 60, lambda: True) == ("ok", "slept 0.0")
    pid = proc.pid
    with pytest.raises(OverBudget):
        proc.run((60.0,), 1.5, lambda: True)
    assert pid is not None and not alive(pid)
    assert proc.run((0.0,), 60, lambda: True) == ("ok", "slept 0.0")


def test_the_budget_the_replay_reports_replaces_the_first(proc):
    notes = []

    def on_note(note):
        notes.append(note)
        return 1.0 + note["sim_s"]

    # the job sleeps 60 s: under the first budget (600 s) it would end normally, so only the reported one kills it
    with pytest.raises(OverBudget):
        proc.run((60.0, 0.5), 600, lambda: True, on_note)
    assert notes == [{"sim_s": 0.5}]


def test_a_cancelled_replay_is_killed(proc):
    calls = []

    def keep_going():
        calls.append(1)
        return len(calls) < 2

    with pytest.raises(Cancelled):
        proc.run((60.0,), 600, keep_going)
    assert not alive(proc.pid or 0) if proc.pid else True


def test_a_crash_is_reported_and_a_refusal_is_one_line():
    p = ReplayProcess("replay_targets:crash")
    try:
        with pytest.raises(ReplayFailed, match="exit code 3"):
            p.run((3,), 60, lambda: True)
    finally:
        p.close()
    p = ReplayProcess("replay_targets:refuse")
    try:
        assert p.run(("no Save",), 60, lambda: True) == ("error", "UserError", "no Save")
    finally:
        p.close()


PARENT = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, {tests!r})
    from chainsim.game.server.replayer import ReplayProcess
    p = ReplayProcess("replay_targets:sleepy")
    p._start()
    print(p.pid, flush=True)
    p.run((600.0,), 900, lambda: True)
    """
)


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_replay_processes_end_with_their_server(sig, tmp_path):
    parent = subprocess.Popen(
        [sys.executable, "-c", PARENT.format(tests=str(TESTS))], stdout=subprocess.PIPE, text=True
    )
    try:
        child = int(parent.stdout.readline())
        time.sleep(1.0)
        assert alive(child)
        parent.send_signal(sig)
        parent.wait(30)
        deadline = time.monotonic() + 10
        while alive(child) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not alive(child), f"replay process {child} outlived its server ({sig.name})"
    finally:
        parent.kill()
        parent.wait()

"""`chainsim bench startup` times a start by the lines the window prints: each figure is the time from starting
the process to its line, the process is ended once all came, and a window that ends early or says too little
within the timeout is one line naming what it said (the real window's starts are in CI's slow tests)."""

from __future__ import annotations

import sys
import time

import pytest

from chainsim.systems.engine.errors import UserError
from chainsim.tools.bench import startup


def _fake(script: str) -> list[str]:
    return [sys.executable, "-c", script]


def test_each_line_is_timed_from_the_start_and_the_window_is_ended():
    script = (
        "import time, sys\n"
        "time.sleep(0.3); print('window: first picture 0.3 s after start', flush=True)\n"
        'time.sleep(0.3); print("kernels: the scene\'s ready 0.6 s after start", flush=True)\n'
        "time.sleep(0.3); print('kernels: all compiled 0.9 s after start', flush=True)\n"
        "time.sleep(60)\n"
    )
    t = time.monotonic()
    got = startup.one_start(_fake(script), {}, timeout=30)
    assert time.monotonic() - t < 20  # ended once all three came, not after its minute
    # each figure is its own line's time from the start: in the order the window printed them, none before
    # the child's first sleep (timed from the start, not from the first line)
    assert 0.3 <= got["first_picture_s"] <= got["input_s"] <= got["all_compiled_s"]


def test_a_window_that_ends_early_or_says_too_little_is_one_line():
    with pytest.raises(UserError, match="ended before it was ready: window: first picture"):
        startup.one_start(_fake("print('window: first picture 0.1 s after start')"), {}, timeout=30)
    with pytest.raises(UserError, match=r"gave \['first_picture_s'\] in 2 s"):
        startup.one_start(_fake("print('window: first picture 0.1 s', flush=True); import time; time.sleep(30)"),
                          {}, timeout=2)  # fmt: skip

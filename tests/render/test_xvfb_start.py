"""Virtual displays for the real-window tests and benchmarks (chainsim.game.trainer.xvfb): two started at once
get two displays, each ready for a client as soon as it is returned."""

from __future__ import annotations

import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor

import pytest

from chainsim.game.trainer.xvfb import start_xvfb

needs_x = pytest.mark.skipif(
    shutil.which("Xvfb") is None or shutil.which("xdotool") is None, reason="needs Xvfb and xdotool"
)


@needs_x
def test_displays_started_together_differ_and_take_clients_at_once():
    with ThreadPoolExecutor(4) as pool:
        started = list(pool.map(lambda size: start_xvfb(*size), [(640, 480), (800, 600), (1024, 768), (320, 240)]))
    try:
        names = [display for _, display in started]
        assert len(set(names)) == 4
        for (_, display), size in zip(started, ["640 480", "800 600", "1024 768", "320 240"], strict=True):
            out = subprocess.run(
                ["xdotool", "getdisplaygeometry"], env={"DISPLAY": display}, capture_output=True, text=True, timeout=10
            )
            assert out.stdout.strip() == size, (display, out.stderr)
    finally:
        for proc, _ in started:
            proc.kill()
            proc.wait()

"""A virtual X display for the real window off a screen: `start_xvfb` starts Xvfb on a display number it
picks itself (``-displayfd``), so two processes starting one at once (tests on two workers, a benchmark
beside them) never take the same number, and returns once the server is ready for clients."""

from __future__ import annotations

import os
import select
import subprocess

#: seconds Xvfb has to say which display it took
READY_S = 30.0


def start_xvfb(width: int, height: int) -> tuple[subprocess.Popen, str]:
    """(the Xvfb process, its display name such as ":93"); RuntimeError when it does not start."""
    r, w = os.pipe()
    try:
        proc = subprocess.Popen(
            ["Xvfb", "-displayfd", str(w), "-screen", "0", f"{width}x{height}x24", "-nolisten", "tcp"],
            pass_fds=(w,),
            stderr=subprocess.DEVNULL,
        )
    finally:
        os.close(w)
    try:
        number = b""
        # Xvfb writes the number once it listens for clients: no guessing how long it takes to start
        while not number.endswith(b"\n"):
            ready, _, _ = select.select([r], [], [], READY_S)
            chunk = os.read(r, 16) if ready else b""
            if not chunk:
                proc.kill()
                raise RuntimeError("Xvfb did not start (no display number within 30 s)")
            number += chunk
    finally:
        os.close(r)
    return proc, f":{int(number)}"

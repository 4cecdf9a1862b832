"""Jobs for replay-process tests (tests/unit/test_replay_process.py): importable by name in a spawned process."""

from __future__ import annotations

import os
import sys
import time


def sleepy(seconds: float, sim_s: float | None = None, report=None) -> str:
    if report is not None and sim_s is not None:
        report({"sim_s": sim_s})
    time.sleep(seconds)
    return f"slept {seconds}"


def crash(code: int, report=None) -> None:
    sys.stdout.flush()
    os._exit(code)


def refuse(message: str, report=None) -> None:
    from chainsim.systems.engine.errors import UserError  # noqa: PLC0415

    raise UserError(message)

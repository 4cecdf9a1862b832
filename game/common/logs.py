"""How the program speaks: `logging` set up once for the command line (messages on stderr).

Command output (tables, summaries, paths) goes to stdout with print; everything else (what a job is
doing, warnings, timings) goes through loggers named after their module, configured here.
"""

from __future__ import annotations

import logging
import sys


class _StderrHandler(logging.StreamHandler):
    """Writes to whatever sys.stderr is at the time of each message (redirections and tests replace it)."""

    _chainsim = True  # marks chainsim's own handler: a second setup_logging (tests run main() many times) adds none

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:  # StreamHandler.__init__ sets it; the property always follows sys.stderr
        pass


def setup_logging(level: int = logging.INFO) -> None:
    """Route every chainsim logger to stderr as plain lines; `level` from -v / -q."""
    root = logging.getLogger("chainsim")
    root.setLevel(level)
    if not any(getattr(h, "_chainsim", False) for h in root.handlers):
        handler = _StderrHandler()
        handler.setFormatter(logging.Formatter("%(message)s"))
        root.addHandler(handler)
    root.propagate = False

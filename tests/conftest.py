"""Shared test setup: headless everywhere, numba threads fixed, helpers to run the CLI in-process."""

from __future__ import annotations

import os

os.environ.setdefault("PYGLET_HEADLESS", "true")
os.environ.pop("CHAINSIM_PACK_PATH", None)

import pytest  # noqa: E402

# records_db / postgres_server: each records test on an SQLite file and on a real PostgreSQL server
pytest_plugins = ["records_db"]


@pytest.fixture
def cli(capsys):
    """Run `chainsim ARGS` in-process; returns (exit code, stdout, stderr)."""
    from chainsim.game.cli.main import main

    def run(*args: str):
        code = main([str(a) for a in args])
        out = capsys.readouterr()
        return code, out.out, out.err

    return run

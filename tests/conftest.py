"""Shared test setup: headless everywhere, numba threads fixed, helpers to run the CLI in-process."""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile

os.environ.setdefault("PYGLET_HEADLESS", "true")
os.environ.pop("CHAINSIM_PACK_PATH", None)
# the built-in scripts press Save, so a run without --db saves to the default records database: in tests
# that is a throwaway file, never the developer's own records (set before any fixture, module-scoped ones too)
_RECORDS = tempfile.mkdtemp(prefix="chainsim-test-records-")
atexit.register(shutil.rmtree, _RECORDS, True)
os.environ["CHAINSIM_DB"] = os.path.join(_RECORDS, "records.sqlite3")

import pytest  # noqa: E402

# records_db / postgres_server: each records test on an SQLite file and on a real PostgreSQL server
pytest_plugins = ["records_db"]


def pytest_configure(config):
    """Compile the project's modules to bytecode once, before any worker starts. A run starts hundreds of
    Python processes (servers, replay processes, command lines, kernel compilers); where the environment
    sets PYTHONDONTWRITEBYTECODE none of them writes what it compiled, so each compiled every module it
    imported again (a quarter of a second a process). They still read bytecode that exists."""
    if hasattr(config, "workerinput"):  # an xdist worker: the controller has done it
        return
    import compileall  # noqa: PLC0415 - only here

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for folder in ("components", "systems", "game", "tools"):
        compileall.compile_dir(os.path.join(root, folder), quiet=1, workers=0)


@pytest.fixture
def cli(capsys):
    """Run `chainsim ARGS` in-process; returns (exit code, stdout, stderr)."""
    from chainsim.game.cli.main import main

    def run(*args: str):
        code = main([str(a) for a in args])
        out = capsys.readouterr()
        return code, out.out, out.err

    return run

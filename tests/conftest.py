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


@pytest.fixture
def cli(capsys):
    """Run `chainsim ARGS` in-process; returns (exit code, stdout, stderr)."""
    from chainsim.game.cli.main import main

    def run(*args: str):
        code = main([str(a) for a in args])
        out = capsys.readouterr()
        return code, out.out, out.err

    return run

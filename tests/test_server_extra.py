"""Without the `server` extra (starlette, uvicorn, websockets, jinja2, psycopg), the commands that serve say
in one line what to install and exit 2, and the simulator's own commands work.

The CLI runs in a subprocess whose interpreter cannot import those packages (None in sys.modules makes
`import starlette` fail as an absent package does), so the check holds on a machine that has them."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
EXTRA = ("starlette", "uvicorn", "websockets", "jinja2", "psycopg")
HINT = "pip install 'chainsim[server]'"

_WITHOUT_EXTRA = f"""
import sys
for name in {EXTRA!r}:
    sys.modules[name] = None
from chainsim.game.cli.main import main
code = main(sys.argv[1:])
leaked = sorted(n for n in {EXTRA!r} if sys.modules.get(n) is not None)
if leaked:
    print("imported:", leaked, file=sys.stderr)
    code = 99
sys.exit(code)
"""


def _chainsim(*argv: str, cwd: Path, stdin: str = "") -> subprocess.CompletedProcess:
    env = dict(os.environ, PYGLET_HEADLESS="true", MPLBACKEND="Agg", CHAINSIM_PROGRESS="0")
    env["CHAINSIM_DB"] = str(cwd / "records.sqlite3")  # never the user's own records
    return subprocess.run(
        [sys.executable, "-c", _WITHOUT_EXTRA, *argv],
        cwd=cwd,
        env=env,
        input=stdin,
        capture_output=True,
        text=True,
        timeout=600,
    )


@pytest.mark.parametrize(
    ("argv", "lead"),
    [
        (("serve", "--port", "8765"), "chainsim serve: the records server's packages are not installed"),
        (("bench", "records", "--db", "b"), "chainsim bench: bench records runs the records server"),
        (("bench", "train", "--json", "b"), "chainsim bench: bench train runs the records server"),
        (("records", "--db", "postgresql://u@127.0.0.1:9/x", "list"), "chainsim records: PostgreSQL records need"),
    ],
)
def test_a_command_that_needs_the_server_extra_says_what_to_install(tmp_path, argv, lead):
    r = _chainsim(*argv, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(lead) and HINT in lines[0], lines[0]
    assert not (tmp_path / "b").exists()  # the benchmarks stop before making anything


def test_serve_help_and_the_simulator_work_without_the_server_extra(tmp_path):
    r = _chainsim("serve", "--help", cwd=tmp_path)
    assert r.returncode == 0 and "--db" in r.stdout, r.stderr
    pack = REPO / "assets" / "loop-demo"
    r = _chainsim("validate", str(pack), cwd=tmp_path)
    assert r.returncode == 0 and "ok" in r.stdout, r.stderr
    r = _chainsim("run", str(pack), "--headless", "--steps", "5", "--out", "out", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["steps"] == 5
    # the local records and the server's accounts (SQLite) need none of the extra
    r = _chainsim(
        "records",
        "user",
        "add",
        "--role",
        "trainee",
        "--class",
        "c1",
        "--password-stdin",
        "alice",
        cwd=tmp_path,
        stdin="a long enough password\n",
    )
    assert r.returncode == 0, r.stderr
    r = _chainsim("records", "user", "list", cwd=tmp_path)
    assert r.returncode == 0 and "alice" in r.stdout, r.stderr

"""Helpers for the bad-input battery: throwaway packs, the CLI in a subprocess with a time limit,
and the CLI as an unprivileged user (root ignores file permissions)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

#: a small valid pack: a 5 x 5 grid pulled by one element, fixed at element 0 (25 elements)
BASE_PACK = """\
[pack]
name = "hard"
format = 1

[meshes.sheet]
primitive = "grid"
extents = [20.0, 20.0, 0.0]
resolution = [4.0, 4.0, 1.0]

[materials.soft]
alpha_min = 0.8
alpha_max = 1.2
beta = 0.1
relax = 2

[entities.body.mesh]
mesh = "sheet"
material = "soft"

[entities.body.deformable]
fixed = [0]

[entities.body.pull]
path = [0.0, 0.0, 5.0]
element = 12
speed = 50.0
"""


@pytest.fixture(autouse=True)
def _private_records(tmp_path, monkeypatch):
    """No test here may save into the user's own records database."""
    monkeypatch.setenv("CHAINSIM_DB", str(tmp_path / "default-records.sqlite3"))


def write_pack(folder: Path, manifest: str, files: dict[str, str | bytes] | None = None) -> Path:
    """A pack folder holding `manifest` as pack.toml and `files` (relative path -> content)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "pack.toml").write_text(textwrap.dedent(manifest), encoding="utf-8")
    for rel, content in (files or {}).items():
        p = folder / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            p.write_bytes(content)
        else:
            p.write_text(content, encoding="utf-8")
    return folder


def chainsim(*args, env: dict | None = None, timeout: float = 120, cwd: Path | None = None):
    """`chainsim ARGS` in a fresh process; a run past `timeout` seconds fails the test (a hang)."""
    full_env = {**os.environ, "PYGLET_HEADLESS": "true", "MPLBACKEND": "Agg", **(env or {})}
    full_env.pop("CHAINSIM_PACK_PATH", None)
    try:
        return subprocess.run(
            [sys.executable, "-m", "chainsim.game.cli.main", *map(str, args)],
            capture_output=True,
            text=True,
            timeout=timeout,
            env=full_env,
            cwd=cwd or ROOT,
        )
    except subprocess.TimeoutExpired:
        pytest.fail(f"chainsim {' '.join(map(str, args))} ran past {timeout} s (a hang)")


def assert_one_line_error(code: int, err: str, *words: str) -> None:
    """Exit 2, no traceback, and every line of stderr names the problem (words in the first)."""
    assert code == 2, (code, err)
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert lines, "no message on stderr"
    text = err.lower()
    for w in words:
        assert w.lower() in text, (w, err)


# -- running as an unprivileged user --------------------------------------------------------------
#
# The interpreter lives under /root here, which nobody cannot read, so modules cannot be imported
# after privileges are dropped. The runner therefore warms up as root first (a run of each kind of
# command, into a scratch folder, which imports everything those commands use), then switches to
# uid 65534 and runs the commands asked for in the same process, one after the other.

_AS_NOBODY = r"""
import contextlib, io, json, os, sys, tempfile
import numpy as np
import chainsim.game.cli.main as main
from chainsim.systems.engine import meshgen

scratch = tempfile.mkdtemp()
pos, links = meshgen.grid((3, 3))
np.savez(os.path.join(scratch, "g.npz"), positions=pos, links=links)
warm = [
    ["run", "prp", "--steps", "2", "--db", os.path.join(scratch, "r.sqlite3"), "--out", os.path.join(scratch, "o")],
    ["run", "loop-demo", "--steps", "2", "--record", os.path.join(scratch, "r.json")],
    ["replay", os.path.join(scratch, "r.json")],
    ["chainmail", os.path.join(scratch, "g.npz"), "--grab", "0", "--to", "1", "1", "--alpha-min", "0.8",
     "--alpha-max", "1.2", "--beta", "0.1", "--out", os.path.join(scratch, "x.npz")],
    ["records", "--db", os.path.join(scratch, "r.sqlite3"), "add-class", "c"],
    ["records", "--db", os.path.join(scratch, "r.sqlite3"), "export", "--csv", os.path.join(scratch, "r.csv")],
]
for argv in warm:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main.main(argv) == 0, argv
os.setgroups([])
os.setgid(65534)
os.setuid(65534)
os.environ["HOME"] = sys.argv[1]
results = []
for argv in json.loads(sys.argv[2]):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main.main(argv)
        except BaseException as e:  # a traceback is a failure the test reports
            import traceback
            traceback.print_exc(file=err)
            code = 99
    results.append([code, out.getvalue(), err.getvalue()])
print(json.dumps(results))
"""


@pytest.fixture
def shared_tmp():
    """A temporary folder an unprivileged user can enter (pytest's own are private to root)."""
    d = Path(tempfile.mkdtemp(prefix="chainsim-hard-"))
    d.chmod(0o755)
    try:
        yield d
    finally:
        subprocess.run(["rm", "-rf", str(d)], check=False)


@pytest.fixture
def as_nobody(shared_tmp):
    """Run a list of `chainsim` argvs as the user nobody (uid 65534); returns [(code, out, err)].

    Skipped unless the tests run as root (only root can switch users; as anyone else, the tests'
    own permissions already apply).
    """
    if os.geteuid() != 0:
        pytest.skip("needs root to switch to an unprivileged user")

    def run(*commands, timeout: float = 300):
        env = {**os.environ, "PYGLET_HEADLESS": "true", "MPLBACKEND": "Agg"}
        env.pop("CHAINSIM_PACK_PATH", None)
        argvs = json.dumps([[str(a) for a in c] for c in commands])
        r = subprocess.run(
            [sys.executable, "-c", _AS_NOBODY, str(shared_tmp), argvs],
            capture_output=True,
            text=True,
            timeout=timeout,
            env=env,
            cwd=ROOT,
        )
        assert r.returncode == 0, r.stderr[-3000:]
        return [tuple(x) for x in json.loads(r.stdout.strip().splitlines()[-1])]

    return run

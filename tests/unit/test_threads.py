"""Threads on a busy machine: the engine's wait policy (set when the user chose none, left alone when
they chose one, and read by the OpenMP runtime), and `chainsim bench models --threads --busy`."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numba
import pytest

from chainsim.game.cli.main import build_parser, main
from chainsim.systems.engine import threads
from chainsim.systems.engine.errors import UserError
from chainsim.tools.bench import models

ROOT = Path(__file__).resolve().parents[2]

# the engine imported as a program would, then its own kernels run: a hybrid body's frame
_FRAME = """
import json, os
import numpy as np
from chainsim.systems.engine import meshgen, threads
from chainsim.systems.engine.bodies.factory import make_body
import numba
pos, tets, _ = meshgen.tet_grid(4, 4, 4)
body = make_body("hybrid", pos, tets=tets, fixed=np.arange(16))
body.grab([63], pos[[63]] + 0.2)
body.step(1 / 60)
names = threads.USER_CHOICES
print(json.dumps({"env": {n: os.environ.get(n) for n in names}, "said": threads.describe(),
                  "layer": numba.threading_layer()}))
"""


def _run_frame(**env: str) -> tuple[dict, str]:
    """The frame in a fresh process whose environment has none of the user's choices but `env`."""
    clean = {k: v for k, v in os.environ.items() if k not in threads.USER_CHOICES}
    r = subprocess.run(
        [sys.executable, "-c", _FRAME],
        env={**clean, "OMP_DISPLAY_ENV": "VERBOSE", **env},
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1]), r.stderr


def test_apply_sets_the_passive_policy_only_where_the_user_chose_nothing():
    env: dict[str, str] = {}
    assert threads.apply(env) == {"OMP_WAIT_POLICY": "PASSIVE"} and env == {"OMP_WAIT_POLICY": "PASSIVE"}
    empty = {"OMP_WAIT_POLICY": ""}  # set to nothing is not a choice
    assert threads.apply(empty) and empty["OMP_WAIT_POLICY"] == "PASSIVE"
    for name in threads.USER_CHOICES:
        chosen = {name: "workqueue" if name == "NUMBA_THREADING_LAYER" else "1"}
        before = dict(chosen)
        assert threads.apply(chosen) == {} and chosen == before, name


def test_a_body_runs_under_the_passive_policy_when_the_user_set_none():
    got, stderr = _run_frame()
    assert got["env"]["OMP_WAIT_POLICY"] == "PASSIVE"
    assert all(got["env"][n] is None for n in threads.USER_CHOICES if n != "OMP_WAIT_POLICY")
    assert got["said"] == "OMP_WAIT_POLICY=PASSIVE (the engine's default)"
    if got["layer"] == "omp" and "GOMP_SPINCOUNT" in stderr:
        # GNU's OpenMP says what it read when numba started it: idle workers do not spin at all
        assert "OMP_WAIT_POLICY = 'PASSIVE'" in stderr and "GOMP_SPINCOUNT = '0'" in stderr


@pytest.mark.parametrize(
    "name, value",
    [("OMP_WAIT_POLICY", "ACTIVE"), ("GOMP_SPINCOUNT", "20000"), ("KMP_BLOCKTIME", "0")],
)
def test_a_policy_the_user_set_is_left_alone(name, value):
    got, stderr = _run_frame(**{name: value})
    assert got["env"] == {n: (value if n == name else None) for n in threads.USER_CHOICES}
    assert got["said"] == f"{name}={value} (set before the start)"
    if got["layer"] == "omp" and name != "KMP_BLOCKTIME" and "GOMP_SPINCOUNT" in stderr:
        spins = "30000000000" if value == "ACTIVE" else value
        assert f"GOMP_SPINCOUNT = '{spins}'" in stderr


def test_a_threading_layer_the_user_chose_is_left_alone():
    got, _ = _run_frame(NUMBA_THREADING_LAYER="workqueue")
    assert got["layer"] == "workqueue" and got["env"]["OMP_WAIT_POLICY"] is None


def _bench_args(*argv: str):
    return build_parser("bench").parse_args(["bench", "models", *argv])


def test_bench_models_threads_flag_compares_one_thread_with_all_beside_two_busy_processes():
    plain = _bench_args()
    assert plain.threads == 1 and models._busy(plain, plain.threads) == 0
    every = _bench_args("--threads")
    assert every.threads == numba.config.NUMBA_NUM_THREADS
    assert models._busy(every, 2) == 2  # what the issue asks: two busy processes beside the comparison
    quiet = _bench_args("--threads", "2", "--busy", "0")
    assert (quiet.threads, quiet.busy, models._busy(quiet, 2)) == (2, 0, 0)


@pytest.mark.parametrize(
    "argv, word",
    [
        (["--busy", "-1"], "--busy"),
        (["--busy", "65"], "--busy"),
        (["--busy", "two"], "--busy"),
        (["--busy", "1e9"], "--busy"),
        (["--threads", "all"], "--threads"),
    ],
)
def test_bench_models_refuses_a_bad_busy_or_threads_value_in_one_line(argv, word, capsys, tmp_path):
    out = tmp_path / "o"
    assert main(["bench", "models", *argv, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert word in err and len(err.splitlines()) == 1 and "Traceback" not in err
    assert not out.exists()


def test_bench_models_run_refuses_a_bad_busy_count(tmp_path):
    args = SimpleNamespace(scene="block", n=6, frames=10, only=None, out=str(tmp_path), busy=1000)
    with pytest.raises(UserError, match="--busy"):
        models.run(args)


@pytest.mark.parametrize("stop", [RuntimeError, KeyboardInterrupt])
def test_busy_processes_end_with_the_measurement_however_it_ends(stop):
    with pytest.raises(stop), models.busy_processes(2) as procs:
        assert len(procs) == 2 and all(p.poll() is None for p in procs)
        raise stop()
    assert all(p.returncode is not None for p in procs)


def _gone(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] in ("Z", "X")
    except FileNotFoundError:
        return True


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads /proc")
def test_busy_processes_leave_when_their_parent_is_killed():
    parent = (
        "import os, sys\nfrom chainsim.tools.bench.models import busy_processes\n"
        "with busy_processes(1) as procs:\n    print(procs[0].pid, flush=True)\n    os._exit(0)\n"
    )
    r = subprocess.run([sys.executable, "-c", parent], capture_output=True, text=True, timeout=120, cwd=ROOT)
    pid = int(r.stdout.split()[0])
    deadline = time.monotonic() + 30  # a bound on the wait, not a timing: it looks up its parent every few ms
    while not _gone(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _gone(pid)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="one numba thread on this machine")
def test_bench_models_with_threads_measures_each_setting_on_one_thread_then_on_all(tmp_path):
    args = SimpleNamespace(
        scene="block", n=6, frames=100, only="projective statics, CG 6", threads=2, busy=1, out=str(tmp_path)
    )
    before = numba.get_num_threads()
    try:
        assert models.run(args) == 0
    finally:
        numba.set_num_threads(before)
    info = json.loads((tmp_path / "results.json").read_text())
    assert [r["threads"] for r in info["rows"]] == [1, 2] and info["threads"] == [1, 2]
    assert info["busy_processes"] == 1 and "1 busy process beside" in info["timing"]
    assert all(r["cpu_ms_per_frame_median"] > 0 for r in info["rows"])
    moving = info["rows"][1]["moving_tool"]
    assert set(moving) == {"1", "2"} and all(m["ms"] > 0 and m["cpu_ms"] > 0 for m in moving.values())
    md = (tmp_path / "results.md").read_text()
    assert "(2 threads)" in md and "moving tool, 1 thread" in md

"""A kernel gives the same bits whether this process compiled it or loaded it from numba's on-disk cache.

The records server scores an upload by replaying it and comparing the state at the Save with the
simulator's digest, so the simulator (which may compile its kernels in its own process) and the
server's replay process (which loads them from the cache) must compute the same numbers. A kernel
compiled with fast-math flags and called from another kernel broke this: compiled together, the
callee was inlined and rearranged with the caller; loaded, it was not, and a held needle's tissue
drifted apart by the last bits within a dozen frames. Each scene runs twice in fresh processes on one
fresh cache directory: first cold (everything compiled there), then warm (everything loaded)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

# each case compiles a scene's kernels in fresh processes, cold then warm (half a minute on 2 cores): CI runs it
pytestmark = pytest.mark.slow

SCENE = r"""
import hashlib, sys
import numpy as np
from chainsim.systems.engine import make_body, tet_grid

rest, tets, links = tet_grid(8, 8, 5, spacing=1.0)
fixed = np.flatnonzero(rest[:, 2] < 1e-9)
top = np.flatnonzero((rest[:, 2] > rest[:, 2].max() - 1e-9) & (np.abs(rest[:, 0] - 3.5) < 1.6)
                     & (np.abs(rest[:, 1] - 3.5) < 1.6))
model = sys.argv[1]
settings = {"exact": True} if model == "chainmail" else {}
body = make_body(model, rest, tets=tets, fixed=fixed, **settings)
digest = hashlib.sha256()
for frame in range(30):
    lift = min(frame, 12)  # a pull, then held still: the frames a needle holds tissue for
    body.grab(top, rest[top] + np.array([0.08 * lift, 0.0, 0.12 * lift]))
    body.step()
    digest.update(np.ascontiguousarray(body.positions).tobytes())
print(digest.hexdigest())
"""


def _run(model: str, cache: str) -> str:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    done = subprocess.run([sys.executable, "-c", SCENE, model], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout.strip()


@pytest.mark.parametrize("model", ["hybrid", "chainmail"])
def test_a_body_moves_the_same_with_its_kernels_compiled_here_or_loaded_from_the_cache(model, tmp_path):
    cache = str(tmp_path / "numba-cache")
    cold = _run(model, cache)
    assert os.listdir(cache), "the first run wrote numba's cache"
    assert _run(model, cache) == cold

"""How numba's worker threads wait between parallel regions (`chainsim.systems.engine.threads`): the
engine's one wait policy, set before any kernel starts the threads.

numba runs the `parallel=True` kernels (the hybrid and projective bodies' local steps and sparse
products, relaxation, normals, the level-parallel cascade) on its threading layer, here OpenMP. By
default GNU's OpenMP keeps an idle worker spinning for about 3 ms (GOMP_SPINCOUNT 300000) after each
parallel region, Intel's and LLVM's for 200 ms (KMP_BLOCKTIME). A frame is many short regions, so on a
machine whose cores are taken by other programs the spinning workers take turns with the one worker
that still has work: beside two busy processes on two cores a hybrid frame on the 10k-node tissue block
took about four times longer on two threads than on one, at five times the CPU; with
OMP_WAIT_POLICY=PASSIVE (honoured by GNU's, Intel's and LLVM's OpenMP) an idle worker sleeps at once
and leaves its core, and two threads took 0.6 to 0.9 of one thread's time at the same CPU
(docs/choosing-a-model.md, "Threads on a busy machine"). The price is a wake-up at the start of every
region, which the level-parallel cascade pays at each of its waves (tools/bench/chainmail.py).

The OpenMP runtime reads these variables once, when numba first loads its threading layer (the first
parallel kernel, or numba.get_num_threads / set_num_threads), so `apply` runs from the engine package's
`__init__`, before any kernel module is imported. A program that started numba's threads before
importing the engine keeps the policy they started with. Anyone who sets one of USER_CHOICES has chosen
how threads wait, or which layer runs them (NUMBA_THREADING_LAYER: tbb and workqueue ignore the OpenMP
variables): the environment is then left as it is.
"""

from __future__ import annotations

import os
from collections.abc import MutableMapping

#: the variables by which a user chooses how idle threads wait, or which threading layer runs them
USER_CHOICES = ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT", "KMP_BLOCKTIME", "NUMBA_THREADING_LAYER")
#: what the engine sets when the user chose none of them
DEFAULT = {"OMP_WAIT_POLICY": "PASSIVE"}

_applied: dict[str, str] = {}


def apply(environ: MutableMapping[str, str] = os.environ) -> dict[str, str]:
    """Set DEFAULT in `environ` unless one of USER_CHOICES is set there (to anything but an empty
    string); returns what was set, {} when the user's choice stands."""
    if any(environ.get(name) for name in USER_CHOICES):
        return {}
    environ.update(DEFAULT)
    if environ is os.environ:
        _applied.update(DEFAULT)
    return dict(DEFAULT)


def describe() -> str:
    """The wait policy of this process in words, for a benchmark's report: the variables that choose it
    and who set them."""
    chosen = {name: os.environ[name] for name in USER_CHOICES if os.environ.get(name)}
    if not chosen:
        return "the threading layer's own wait policy"
    words = ", ".join(f"{name}={value}" for name, value in chosen.items())
    return f"{words} (the engine's default)" if chosen == _applied else f"{words} (set before the start)"

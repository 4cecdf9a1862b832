"""Compiling the numba kernels ahead, so no interaction ever waits on compilation.

numba compiles a kernel the first time it runs (seconds each on a fresh install) and caches the
result on disk (cache=True). The kernels come in groups (`GROUPS`), each run once on a tiny input
with every argument type the app passes. `warm_up()` runs them in this process with a progress bar;
with a warm cache that costs a fraction of a second (loading the cached machine code).

`Compiler` runs the groups in child processes instead (`python -m chainsim.systems.engine.warmup`, one
group at a time on request, `PROCESSES` of them taking the next group as each finishes): the window
opens at once and reads the progress while they work, and a process holds no lock another needs
(a thread compiling in the window's process would hold the GIL for seconds at a time). The groups a
pack needs go first (`Compiler(first=...)`). What a child compiles lands in numba's on-disk cache,
from which the window's process then loads it on first call. Two children may compile one helper
kernel (the exact-limit pass serves every ChainMail order); numba writes a kernel's cache index by
read, modify, write, so each child takes a file lock around that write (`_lock_cache_index`), else
one child's entry could replace the other's and the kernel compile a second time later.
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable

import numba
import numpy as np

from chainsim.systems.engine import needle_force
from chainsim.systems.engine.bodies.chainmail import ChainMailBody
from chainsim.systems.engine.bodies.hybrid import HybridBody
from chainsim.systems.engine.bodies.projective import ProjectiveBody
from chainsim.systems.engine.bodies.surface import SurfaceChainMailBody
from chainsim.systems.engine.bodies.xpbd import XPBDBody
from chainsim.systems.engine.chainmail_params import ORDERS
from chainsim.systems.engine.haptics import servo as haptic_servo
from chainsim.systems.engine.kernels import waves
from chainsim.systems.engine.kernels.chainmail import cascade
from chainsim.systems.engine.kernels.normals import (
    PARALLEL_THREADS,
    _normals_parallel,
    moved_normals_kernel,
    vertex_normals_kernel,
)
from chainsim.systems.engine.kernels.projective import pcg3
from chainsim.systems.engine.kernels.twolevel import det_at
from chainsim.systems.engine.meshgen import tet_grid, triangulated_grid
from chainsim.systems.engine.progress import progress
from chainsim.systems.engine.segment_tree import SegmentTree

#: child processes compiling at once (a third would only share the same cores on a two-core machine)
PROCESSES = max(1, min(2, os.cpu_count() or 1))
#: the nice increment of a child compiling what nothing waits on (the window draws and answers first)
BACKGROUND_NICE = 10


def _grid():
    rest, tets, links = tet_grid(3, 3, 3, spacing=1.0)
    _p2, tris, _l2 = triangulated_grid(3, 3, spacing=1.0, dim=3)
    return rest, tets, links, tris


def _chainmail(order: str, dtype) -> None:
    rest, _tets, links, _tris = _grid()
    # numba compiles one version per argument type: with and without anchors
    for fixed in ([0], None):
        body = ChainMailBody(rest, links, relax=2, exact=True, order=order, dtype=dtype, fixed=fixed)
        # a pull out of reach, then the same element dragged on: the second searches against the fixed
        # elements' field (exact._pin_field), as a drag does
        for far in (0.5, 0.6):
            body.grab([len(rest) - 1], rest[-1] + far)
        body.step()  # every body's step checks its rows (kernels.rows), one version per precision
        body.cut(rest[0] - 1.0, rest[-1] + 1.0, normal=[0.0, 0.0, 1.0], depth=10.0)


def _parallel_cascade(dtype) -> None:
    # the level-parallel cascade, which a body takes by itself on large meshes with many threads
    rest, _tets, links, _tris = _grid()
    body = ChainMailBody(rest, links, dtype=dtype)
    t = (body.rest[-1] + 0.5)[None]
    cascade(body.rest, body.positions, body.graph, body.amin, body.amax, body.beta, [len(rest) - 1], t,
            workspace=body.workspace, parallel=True)  # fmt: skip


def _pull(body) -> None:
    # two pulls (a moving target takes the hybrid body's linear start), then a release
    for lift in (0.1, 0.15):
        body.grab([1], body.rest[1] + lift)
        body.step(1 / 60)
    body.release()
    body.step(1 / 60)


def _hybrid() -> None:
    # the hybrid body as packs set it up (no sleeping), pulled; what a tissue scene waits for
    rest, tets, _links, _tris = _grid()
    body = HybridBody(rest, tets, fixed=[0])
    _pull(body)
    # the start's look at the element that failed it last time (a tool held short in tissue)
    det_at(body.x, body.tets, body.D, np.int64(0))


def _models() -> None:
    rest, tets, _links, tris = _grid()
    for make in (
        lambda: XPBDBody(rest, tets, fixed=[0]),  # corotational, the default
        lambda: XPBDBody(rest, tets, constraints="neohookean", fixed=[0]),
        lambda: XPBDBody(rest, tets, constraints="stvk", fixed=[0]),
        lambda: XPBDBody(rest[: tris.max() + 1], triangles=tris, fixed=[0]),
        lambda: ProjectiveBody(rest, tets, fixed=[0]),
        lambda: ProjectiveBody(rest[: tris.max() + 1], triangles=tris, fixed=[0]),
        # the m key reaches this too on sheets (the cutting layers)
        lambda: SurfaceChainMailBody(rest[: tris.max() + 1], tris, fixed=[0]),
        lambda: HybridBody(rest, tets, fixed=[0], sleep=0.01),  # the wake front and its drift rings
    ):
        _pull(make())
    # a bar long enough that a pull at one end leaves sleepers at the other: their far field
    bar, bar_tets, _ = tet_grid(10, 2, 2, spacing=1.0)
    _pull(HybridBody(bar, bar_tets, fixed=[0], sleep=0.01, wake_rings=1))
    # the hybrid line search's last resort (projective dynamics' CG step), which a small pull never needs
    n = len(rest)
    indptr, indices = np.arange(n + 1, dtype=np.int64), np.arange(n, dtype=np.int64)
    pcg3(indptr, indices, np.ones(n), np.ones(n), np.ones((n, 3)), np.zeros((n, 3)), 2, 1e-10,
         *(np.zeros((n, 3)) for _ in range(4)))  # fmt: skip


def _csr(tris: np.ndarray, n: int):
    flat = tris.ravel()
    ptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(flat, minlength=n), out=ptr[1:])
    return ptr, (np.argsort(flat, kind="stable") // 3).astype(np.int64)


def _geometry() -> None:
    # what every scene calls once it is drawn and a needle moves: the first uploads' normals and the
    # needle's collision query
    rest, _tets, _links, tris = _grid()
    tris = np.ascontiguousarray(tris, dtype=np.int64)
    n = int(tris.max()) + 1
    # a GPU mesh's first normals: its float32 positions into float64 (chainsim.game.render.meshbuf.GpuMesh)
    vertex_normals_kernel(np.ascontiguousarray(rest[:n], dtype=np.float32), tris, np.zeros((n, 3)))
    SegmentTree.build(rest, tris).first_hit(rest[0] - 1.0, rest[-1] + 1.0)
    # the needle's force on soft tissue (a tissue pack's needle evaluates it every frame; a second to compile)
    lengths = np.array([1.0, 2.0])
    needle_force.axial_force(1.0, 0.2, 10.0, True, 0.3, lengths, lengths, lengths, lengths, 5.0, 0.5, 0.1)
    needle_force.press_force(1.0, 0.2, 10.0)  # also called on its own (a boundary's tenting)


def _moving_normals() -> None:
    # the argument types the window passes: its GPU meshes' float32 positions (chainsim.game.render.meshbuf:
    # whole-mesh normals into the float32 copy, and the moved vertices' normals while a tool drags
    # tissue); missing one froze a first instrument grip for seconds. The engine's float64 positions
    # never reach these kernels, so no float64 version is compiled
    rest, _tets, _links, tris = _grid()
    tris = np.ascontiguousarray(tris, dtype=np.int64)
    n = int(tris.max()) + 1
    ptr, idx = _csr(tris, n)
    pos = np.ascontiguousarray(rest[:n], dtype=np.float32)
    vertex_normals_kernel(pos, tris, np.zeros((n, 3), np.float32))
    normals = np.zeros((n, 3), np.float32)
    moved_normals_kernel(pos, tris, ptr, idx, np.arange(2, dtype=np.int64), np.zeros(n, np.bool_), normals)
    # large meshes on machines with several cores take the parallel gather (float32, the GPU copy);
    # with fewer threads normals_into never calls it, and a parallel kernel is slow to compile
    if numba.config.NUMBA_NUM_THREADS >= PARALLEL_THREADS:
        _normals_parallel(pos, tris, ptr, idx, np.zeros((n, 3), np.float32), 2)


#: the kernel groups, in the order they are compiled when nothing asks for another first: what every
#: window draws with (normals), a needle's collisions and force first, then each model a pack can pick
#: (a pack's own go first: Compiler.prefer); each group holds what a scene of that model calls, so a
#: scene waits only on its own (chainsim.game.trainer.compiling.needed_groups)
GEOMETRY = "normals and collision"
MOVING = "normals of moving meshes"
HYBRID = "hybrid"  # the hybrid body as packs set it up
#: and SurfaceChainMail, a sleeping hybrid body and its CG fallback: what only the m key or a rarer setting reaches
MODELS = "XPBD and projective"
HAPTICS = "haptics"  # the servo's kernels (a force-feedback device on the needle: chainsim.systems.engine.haptics)
PRECISIONS = {"float64": np.float64, "float32": np.float32}


def chainmail_group(order: str, dtype: str = "float64") -> str:
    """The group holding ChainMail's kernels for one cascade order and precision."""
    return f"ChainMail {order} {dtype}"


PARALLEL = "ChainMail level-parallel"

GROUPS: dict[str, Callable[[], None]] = {
    GEOMETRY: _geometry,
    HYBRID: _hybrid,  # the longest a tissue scene waits on: begun beside the normals
    MOVING: _moving_normals,
    PARALLEL: lambda: _parallel_cascade(np.float64),  # long (a parallel kernel), shares nothing: begun early
    **{
        chainmail_group(order, name): functools.partial(_chainmail, order, dtype)
        for order in ORDERS
        for name, dtype in PRECISIONS.items()
    },
    f"{PARALLEL} (float32)": lambda: _parallel_cascade(np.float32),
    MODELS: _models,
    HAPTICS: haptic_servo.warm,
}


def reachable(threads: int | None = None) -> list[str]:
    """The groups `chainsim warmup` and the window compile unasked: every kernel a built-in pack can
    call on a machine where numba has `threads` threads (default: its own count). Left out until a
    pack asks for them (`Compiler.prefer`) or `chainsim warmup --all`: ChainMail in float32 (a pack's
    `deformable.dtype`; no built-in pack sets it, and it would compile each order a second time), and
    with fewer threads than kernels.waves.AUTO_MIN_THREADS the level-parallel cascade, which a body
    then never takes (waves.parallel_wins; a parallel kernel is the slowest to compile)."""
    threads = numba.config.NUMBA_NUM_THREADS if threads is None else threads
    out = [n for n in GROUPS if "float32" not in n]
    if threads < waves.AUTO_MIN_THREADS:
        out.remove(PARALLEL)
    return out


def family(name: str) -> str:
    """Groups of one family share most of their kernels (every ChainMail order of one precision shares
    relaxation and the exact-limit pass): one of them runs alone until it is done, and the others then
    load the shared kernels from the cache instead of compiling them a second time alongside."""
    if name == MODELS:  # its sleeping hybrid body calls every kernel the hybrid group compiles
        return HYBRID
    return name.rsplit(" ", 1)[1] if name.startswith("ChainMail ") and name.endswith(tuple(PRECISIONS)) else name


def warm_up(groups: Iterable[str] | None = None) -> None:
    """Run kernel groups (default: every `reachable` one) once in this process, compiling each or
    loading it from numba's cache."""
    names = reachable() if groups is None else list(groups)
    bar = progress(total=len(names), desc="compiling kernels", unit="group")
    try:
        for name in names:
            bar.set_postfix_str(name)
            GROUPS[name]()
            bar.update(1)
    finally:
        bar.close()


def _lock_cache_index() -> None:
    """Make numba's cache-index update (read the index, add an entry, write it) one step across processes."""
    try:
        import fcntl  # noqa: PLC0415 - Unix only

        from numba.core.caching import IndexDataCacheFile  # noqa: PLC0415 - numba's internals, children only
    except ImportError:  # no fcntl (Windows) or another numba: its own update, as without children
        return
    save = IndexDataCacheFile.save

    def _locked_save(self, key, data):
        with open(f"{self._index_path}.lock", "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            try:
                save(self, key, data)
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)

    IndexDataCacheFile.save = _locked_save


def _child(nice: int = BACKGROUND_NICE) -> int:
    """A compiling child at `nice` (an increment): reads group names from stdin, one per line, answers
    'done NAME' or 'failed NAME: why'."""
    _lock_cache_index()
    if nice and hasattr(os, "nice"):  # the window that waits on us draws first (its first picture)
        os.nice(nice)
    print("ready", flush=True)
    for line in sys.stdin:
        name = line.strip()
        if not name:
            continue
        try:
            GROUPS[name]()
        except Exception as e:  # the window then compiles that group itself when it is needed
            print(f"failed {name}: {type(e).__name__}: {e}".replace("\n", " "), flush=True)
        else:
            print(f"done {name}", flush=True)
    return 0


class Compiler:
    """Compiles the kernel groups in up to `processes` child processes while the caller goes on.

    `first` names the groups wanted soonest (a pack's own); they are handed out before the others.
    `done` (groups finished, failed ones too: their kernels then compile where they are first called),
    `failed` (name -> why) say how far it got, from any thread; `ready(names)` whether
    those groups are done;
    `wait()` blocks until all are. `seconds` is the time from start to the last group. `groups`
    defaults to the `reachable` ones; a group `first` or `prefer` names joins them.

    The children start at nice BACKGROUND_NICE so that the window's first picture is not slowed; once
    the window is up, `hurry(names)` makes the groups the scene waits on compile at normal priority (a
    child of its own for those not begun; one running lowered where the system lets it) while the
    rest stay at BACKGROUND_NICE. `ran_at` (group -> nice increment) says where each one compiled.
    """

    def __init__(self, first: Iterable[str] = (), processes: int | None = None, groups: Iterable[str] | None = None):
        names = reachable() if groups is None else list(groups)
        first = [n for n in dict.fromkeys(first) if n in GROUPS]
        self.queue = deque(first + [n for n in names if n not in first])
        self.total = len(self.queue)
        self.done: list[str] = []
        self.failed: dict[str, str] = {}
        self.running: dict[int, str] = {}
        self.started = time.perf_counter()
        self.seconds: float | None = None
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._finished = threading.Event()
        self._procs: list[subprocess.Popen] = []
        self._processes = processes or PROCESSES
        self._alive = 0
        self._workers = 0  # feeding threads started (their numbers)
        self.urgent: set[str] = set()  # the groups the scene waits on (`hurry`)
        self.ran_at: dict[str, int] = {}
        self._nice: dict[int, int] = {}  # worker -> the nice increment its child has now
        self._pids: dict[int, int] = {}
        with self._lock:
            self._start_workers()
        if not self._alive:
            self._finished.set()
            self.seconds = 0.0

    def _start_workers(self) -> None:
        """Start feeding threads (each with its child process) up to the process count or the queue's
        length (with the lock held)."""
        while self._alive < min(max(1, self._processes), len(self.queue)):
            self._alive += 1
            self._workers += 1
            i = self._workers - 1
            threading.Thread(target=self._feed, args=(i,), daemon=True, name=f"chainsim-compile-{i}").start()

    def _eligible(self, name: str) -> bool:
        fam = family(name)
        if any(family(d) == fam for d in self.done):
            return True
        return not any(family(r) == fam for r in self.running.values())

    def _next(self, worker: int, urgent_only: bool = False) -> str | None:
        with self._changed:
            self.running.pop(worker, None)
            self._changed.notify_all()
            while names := [n for n in self.queue if n in self.urgent or not urgent_only]:
                name = next((n for n in names if self._eligible(n)), None)
                if name is not None:
                    self.queue.remove(name)
                    self.running[worker] = name
                    self._renice(worker, 0 if name in self.urgent else BACKGROUND_NICE)
                    self.ran_at[name] = self._nice.get(worker, BACKGROUND_NICE)
                    return name
                self._changed.wait(0.5)  # a group of the same family is running: wait until it is done
            self._retire()  # now, under the lock: a group `prefer` adds after this starts another feeder
            return None

    def _retire(self) -> None:
        """One feeder fewer (with the lock held); the last one marks the compiler finished."""
        self._alive -= 1
        if self._alive == 0:
            self.seconds = time.perf_counter() - self.started
            self._finished.set()

    def _renice(self, worker: int, nice: int) -> None:
        """Give worker's child the increment `nice` (with the lock held); lowering it may be refused
        (an ordinary user cannot): it then keeps the one it has."""
        pid = self._pids.get(worker)
        if pid is None or self._nice.get(worker) == nice or not hasattr(os, "setpriority"):
            return
        try:
            os.setpriority(os.PRIO_PROCESS, pid, min(19, os.getpriority(os.PRIO_PROCESS, 0) + nice))
        except OSError:
            return
        self._nice[worker] = nice

    def _feed(self, worker: int, nice: int = BACKGROUND_NICE, urgent_only: bool = False) -> None:
        proc = None
        retired = False
        try:
            proc = subprocess.Popen(
                [sys.executable, "-m", "chainsim.systems.engine.warmup", "--child", str(nice)],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                text=True,
                bufsize=1,
            )
            with self._lock:
                self._procs.append(proc)
                self._pids[worker] = proc.pid
                self._nice[worker] = nice
            stdin, stdout = proc.stdin, proc.stdout
            assert stdin is not None and stdout is not None  # both pipes (PIPE above)
            if stdout.readline().strip() != "ready":
                raise RuntimeError("the compiling process did not start")
            while True:
                name = self._next(worker, urgent_only)
                if name is None:  # no group left: _next has retired this feeder
                    retired = True
                    break
                stdin.write(name + "\n")
                stdin.flush()
                reply = stdout.readline().strip()
                with self._lock:
                    if reply == f"done {name}":
                        self.done.append(name)
                    else:
                        self.failed[name] = reply.partition(": ")[2] or "the compiling process ended"
                        self.done.append(name)  # its family's shared kernels are no longer awaited
        except Exception as e:  # no child process: what is left compiles where it is first called
            with self._lock:
                self.running.pop(worker, None)
                if self._alive == 1:
                    for name in self.queue:
                        self.failed[name] = f"{type(e).__name__}: {e}"
                        self.done.append(name)
                    self.queue.clear()
        finally:
            if proc is not None:
                try:
                    if proc.stdin is not None:  # a pipe (PIPE above); typeshed leaves it optional
                        proc.stdin.close()
                    proc.wait(timeout=10)
                except Exception:
                    proc.kill()
            if not retired:
                with self._lock:
                    self._retire()

    def prefer(self, names: Iterable[str]) -> None:
        """Hand out the groups `names` (those not begun yet) before any other; one not among this
        compiler's groups (a pack's float32 ChainMail) joins them, and the children start again if they
        had finished."""
        with self._lock:
            begun = set(self.done) | set(self.running.values())
            first = [n for n in dict.fromkeys(names) if n in GROUPS and n not in begun]
            added = [n for n in first if n not in self.queue]
            self.queue = deque(first + [n for n in self.queue if n not in first])
            if added:
                self.total += len(added)
                self._finished.clear()
                self.seconds = None
                self._start_workers()

    def hurry(self, names: Iterable[str]) -> None:
        """The groups `names` are waited on now (the window is up): those not handed out yet compile in
        a child at normal priority of its own, and a child already on one is lowered to it where the
        system lets it; the other groups keep BACKGROUND_NICE."""
        with self._lock:
            self.urgent = {n for n in names if n in GROUPS and n not in self.done}
            for worker, name in self.running.items():
                if name in self.urgent:
                    self._renice(worker, 0)
                    self.ran_at[name] = self._nice.get(worker, BACKGROUND_NICE)
            if any(n in self.urgent for n in self.queue):
                self._alive += 1
                self._workers += 1
                i = self._workers - 1
                args = (i, 0, True)
                threading.Thread(target=self._feed, args=args, daemon=True, name=f"chainsim-compile-{i}").start()

    def ready(self, names: Iterable[str] | None = None) -> bool:
        """Whether the groups `names` (default: all) need no more compiling here."""
        if names is None:
            return self._finished.is_set()
        with self._lock:
            have = set(self.done)
        return all(n in have or n not in GROUPS for n in names)

    def compiling(self) -> list[str]:
        """The groups being compiled now."""
        with self._lock:
            return list(self.running.values())

    def wait(self, timeout: float | None = None) -> bool:
        return self._finished.wait(timeout)

    def close(self, timeout: float = 10.0) -> None:
        """Wait for the child processes to end (after `wait()`: they end once the groups run out)."""
        with self._lock:
            procs = list(self._procs)
        for proc in procs:
            try:
                proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

    def stop(self) -> None:
        """Hand out no more groups (the window closed first). A child ends after the group it is on, so
        nothing it writes into the cache is cut off half-way."""
        with self._lock:
            self.queue.clear()


if __name__ == "__main__" and sys.argv[1:2] == ["--child"]:
    sys.exit(_child(int(sys.argv[2]) if len(sys.argv) > 2 else BACKGROUND_NICE))

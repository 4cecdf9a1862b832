"""The processes that replay uploads for the scorer: one per scoring thread, killable, dying with the server.

A replay is CPU work in a process of its own (the ECS world is per process). ``ReplayProcess`` keeps
one such process warm between replays (its imports and compiled kernels are paid once) and runs
one job at a time in it, waiting in short slices so that its caller can renew its claim on the
upload, notice that the upload was cancelled, and kill a replay past its time budget; a killed or
crashed process is replaced on the next job.

Replay processes end with the server however it ends: on a clean stop the scorer kills them; on
``kill -9`` the kernel kills them (``PR_SET_PDEATHSIG`` on Linux), and each also watches its parent
and exits once it is gone (other systems, or a parent that dies between fork and the signal being
armed). So a restarted server never finds an old replay still running beside its own.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

logger = logging.getLogger(__name__)

#: how often a waiting caller is called back (seconds), and how often a child looks for its parent
SLICE_S = 1.0
PARENT_CHECK_S = 0.5
#: replays a process runs before it is replaced (memory a large recording left behind is returned)
JOBS_PER_PROCESS = 50


class ReplayFailed(Exception):
    """The replay process died or was killed (not the recording's fault, or not known to be)."""


class Cancelled(Exception):
    """The caller's ``keep_going`` said stop: the replay was killed."""


class OverBudget(Exception):
    """The replay ran past its time budget and was killed."""


def _die_with_parent(parent: int) -> None:
    """Ask the kernel to kill this process when its parent dies, and watch the parent as well."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        except OSError:
            logger.debug("prctl unavailable; watching the parent only")

    def watch() -> None:
        while True:
            if os.getppid() != parent:
                os._exit(0)
            time.sleep(PARENT_CHECK_S)

    if os.getppid() != parent:  # the parent died before the signal was armed
        os._exit(0)
    threading.Thread(target=watch, name="parent-watch", daemon=True).start()


def _child(conn: Any, parent: int, target: str) -> None:
    """The replay process: run ``target`` (``module:function``) on each job received, send back its answer."""
    _die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the server, which stops its scorers
    module, name = target.split(":")
    fn = getattr(__import__(module, fromlist=[name]), name)
    while True:
        try:
            args = conn.recv()
        except (EOFError, OSError):
            return

        def report(note: dict) -> None:  # told to the caller while the job runs (the replay's budget)
            conn.send(("note", note))

        try:
            answer: tuple = ("ok", fn(*args, report=report))
        except BaseException as exc:  # sent back as one line; the process stays for the next job
            answer = ("error", type(exc).__name__, str(exc)[:500])
        try:
            conn.send(answer)
        except (EOFError, OSError):
            return


class ReplayProcess:
    """One warm replay process running ``target`` (``"module:function"``); ``run`` a job, ``close`` it."""

    def __init__(self, target: str) -> None:
        self.target = target
        self._proc: Any = None
        self._conn: Any = None
        self._jobs = 0

    def _start(self) -> None:
        ctx = multiprocessing.get_context("spawn")  # a fresh interpreter, never a fork of the server's threads
        parent, child = ctx.Pipe()
        self._proc = ctx.Process(target=_child, args=(child, os.getpid(), self.target), daemon=True)
        self._proc.start()
        child.close()
        self._conn, self._jobs = parent, 0

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def run(
        self,
        args: tuple,
        budget_s: float,
        keep_going: Callable[[], bool],
        on_note: Callable[[dict], float] | None = None,
    ) -> tuple:
        """``("ok", value)`` or ``("error", type name, message)`` from the target; raises ReplayFailed,
        Cancelled (``keep_going()`` turned false) or OverBudget (past ``budget_s`` seconds, which a note the
        target reports may set anew through ``on_note``, returning the new budget)."""
        if self._proc is None or not self._proc.is_alive() or self._jobs >= JOBS_PER_PROCESS:
            self.close()
            self._start()
        self._jobs += 1
        # this job's process and pipe, held here: close() from another thread (the server stopping) clears
        # the attributes, and the job then ends as a failed replay rather than an error in this thread
        proc, conn = self._proc, self._conn
        start = time.monotonic()
        try:
            conn.send(args)
            while True:
                if conn.poll(SLICE_S):
                    answer = conn.recv()
                    if answer[0] != "note":
                        return answer
                    if on_note is not None:
                        budget_s = on_note(answer[1])
                    continue
                if not proc.is_alive():
                    raise ReplayFailed(f"the replay process ended (exit code {proc.exitcode})")
                if not keep_going():
                    self.close()
                    raise Cancelled()
                if time.monotonic() - start > budget_s:
                    self.close()
                    raise OverBudget()
        except (EOFError, OSError, ValueError):  # ValueError: the pipe was closed under this thread
            proc.join(timeout=5)
            code = proc.exitcode
            self.close()
            raise ReplayFailed(f"the replay process ended (exit code {code})") from None

    def close(self) -> None:
        """Kill the process (if any) and wait for it."""
        proc, self._proc = self._proc, None
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        if proc is not None and proc.is_alive():
            proc.kill()
        if proc is not None:
            proc.join(timeout=10)

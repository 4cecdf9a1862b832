"""The 1 kHz servo loop: a thread running one compiled kernel that never takes the GIL, fed by the 60 Hz simulation.

`Servo` owns the arrays the loop and the simulation share: a mailbox the simulation writes a new model
into each frame (`refresh`, a seqlock: the sequence number is odd while it writes, and the loop takes
the model only if the number was even and unchanged across its copy), the loop's own model and state,
the simulated hand and its trajectory, a ring log of every tick (simdevice's L_* columns) and the time
each tick woke. How it runs (`mode`):

- "kernel" (the default): a thread calls `servo_loop`, a nopython, nogil kernel that sleeps to each
  tick's deadline (clock_nanosleep on absolute time), takes a refreshed model, ticks the device and the
  contact model, logs, and goes round until told to stop. Nothing in it needs the GIL, so neither the
  frame's Python, nor a compile, nor the garbage collector holds it up; the thread asks for SCHED_FIFO
  (Linux, where permitted) so that ordinary processes on a busy machine do not either.
- "python": a Python thread sleeps with time.sleep and calls one compiled tick per period. It needs the
  GIL every tick, and waits for it behind the frame's Python (sys.getswitchinterval, 5 ms by default):
  kept to measure what the kernel loop avoids, and for drivers whose device calls are Python.
- "lockstep": no thread; `advance(tick)` runs the ticks up to `tick` at once, in the caller. A headless
  run steps the servo with the simulation's clock this way, so the same input gives the same forces.

A tick later than a whole period after its deadline counts the deadlines it passed as missed and the
loop goes on from the next one (no burst of ticks to catch up). `stats()` gives the tick periods.
"""

from __future__ import annotations

import ctypes
import os
import sys
import threading
import time

import numpy as np
from numba import njit

from chainsim.systems.engine.haptics import model as M
from chainsim.systems.engine.haptics import simdevice as D
from chainsim.systems.engine.haptics.clock import fence, now_ns, scratch, sleep_until
from chainsim.systems.engine.haptics.port import Depth, DeviceSample, Lateral

# ctl: the loop's controls and counters
CT_STOP = 0  # set to 1 to end the loop
CT_TICKS = 1  # ticks done (published after the tick's log row is written)
CT_MISSED = 2  # deadlines passed without a tick
CT_PERIOD = 3  # ns
CT_SPIN = 4  # ns before each deadline spent spinning instead of sleeping (0: sleep only)
CT_LIMIT = 5  # stop after this many ticks (0: run until stopped)
CTL_SIZE = 8

MODES = ("kernel", "python", "lockstep")
#: SCHED_FIFO priority asked for (above every ordinary thread, below the kernel's own)
RT_PRIORITY = 40
LOG_TICKS = 1 << 18  # 262 s of 1 kHz ticks in the ring


@njit(cache=True, nogil=True)
def take_refresh(mailbox, seq, scratch_model, model, state):
    """Take the mailbox's model if the simulation wrote a new one and was not writing during the copy."""
    s = seq[0]
    if s == seq[1] or s % 2 == 1:
        return False
    fence()
    scratch_model[:] = mailbox
    fence()
    if seq[0] != s:
        return False  # written meanwhile: taken next tick
    seq[1] = s
    M.apply_model(scratch_model, model, state)
    return True


@njit(cache=True, nogil=True)
def _tick(cfg, mailbox, seq, scratch_model, model, state, traj, hand, log, ctl):
    """One tick: a refreshed model if there is one, the device and the contact model; then published."""
    k = ctl[CT_TICKS]
    take_refresh(mailbox, seq, scratch_model, model, state)
    D.device_tick(cfg, model, state, traj, hand, log, k % log.shape[0], k)
    fence()  # the row is written before the count that publishes it
    ctl[CT_TICKS] = k + 1


@njit(cache=True, nogil=True)
def servo_loop(cfg, mailbox, seq, scratch_model, model, state, traj, hand, log, times, ctl):
    """Tick at ctl[CT_PERIOD] ns until ctl[CT_STOP] (or CT_LIMIT ticks); times[k % len] = when tick k woke."""
    buf = np.zeros(2, np.int64)
    period, spin = ctl[CT_PERIOD], ctl[CT_SPIN]
    deadline = now_ns(buf)
    while ctl[CT_STOP] == 0 and (ctl[CT_LIMIT] == 0 or ctl[CT_TICKS] < ctl[CT_LIMIT]):
        deadline += period
        while now_ns(buf) < deadline - spin:
            sleep_until(buf, deadline - spin)  # again if a signal woke it early
        t = now_ns(buf)
        while t < deadline:
            t = now_ns(buf)
        late = t - deadline
        if late >= period:
            ctl[CT_MISSED] += late // period
            deadline += (late // period) * period
        times[ctl[CT_TICKS] % times.shape[0]] = t
        _tick(cfg, mailbox, seq, scratch_model, model, state, traj, hand, log, ctl)
        fence()


@njit(cache=True, nogil=True)
def run_ticks(cfg, mailbox, seq, scratch_model, model, state, traj, hand, log, ctl, until):
    """Ticks up to tick `until` at once (lockstep), taking a refreshed model before each."""
    while ctl[CT_TICKS] < until:
        _tick(cfg, mailbox, seq, scratch_model, model, state, traj, hand, log, ctl)


@njit(cache=True, nogil=True)
def port_tick(cfg, mailbox, seq, scratch_model, model, state, log, ctl, x_h):
    """One tick for a device read through a port (the hand at depth x_h): the force to render (N along
    the needle, positive resisting insertion), logged with no trajectory (ref NaN)."""
    k = ctl[CT_TICKS]
    take_refresh(mailbox, seq, scratch_model, model, state)
    f = M.contact_tick(cfg, model, state, x_h)
    row = k % log.shape[0]
    log[row, D.L_TICK], log[row, D.L_REF], log[row, D.L_HAND] = k, np.nan, x_h
    log[row, D.L_TOOL], log[row, D.L_FORCE], log[row, D.L_PASSED] = state[M.S_XT], f, state[M.S_P]
    log[row, D.L_EVENT], log[row, D.L_WALL] = state[M.S_EVENT], state[M.S_WALL]
    fence()
    ctl[CT_TICKS] = k + 1
    return f


def realtime_thread() -> str:
    """Make the calling thread a real-time one where the system allows: SCHED_FIFO and 1 ns timer slack
    (Linux). Returns what it got, in words."""
    said = []
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None)
            libc.prctl(29, ctypes.c_ulong(1), ctypes.c_ulong(0), ctypes.c_ulong(0), ctypes.c_ulong(0))  # TIMERSLACK
        except (OSError, AttributeError):
            pass
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(RT_PRIORITY))  # 0: this thread
        said.append(f"SCHED_FIFO {RT_PRIORITY}")
    except (AttributeError, OSError) as e:
        said.append(f"ordinary scheduling (SCHED_FIFO refused: {getattr(e, 'strerror', None) or e})")
    return ", ".join(said)


class Servo:
    """The servo loop over a simulated device (`traj`, `hand`), run by `mode` (module docstring)."""

    def __init__(
        self, cfg: np.ndarray, traj: np.ndarray, hand: np.ndarray, mode: str = "kernel", spin_us=0.0, port=None
    ):
        if mode not in MODES:
            raise ValueError(f"servo mode {mode!r}: expected one of {', '.join(MODES)}")
        if port is not None and mode != "python":
            raise ValueError("a device read through a port is ticked by a Python thread (mode 'python')")
        self.cfg, self.mode, self.port = cfg, mode, port
        self.traj = np.ascontiguousarray(traj, dtype=np.float64)
        self.hand = hand
        self.mailbox, self.scratch_model = M.new_model(), M.new_model()
        self.seq = np.zeros(2, dtype=np.int64)
        self.model, self.state = M.new_model(), M.new_state()
        # filled, not only allocated: the pages are the process's before the loop writes them (a first
        # write to a fresh page is a page fault, slow when the machine is short of memory)
        self.log = np.full((LOG_TICKS, D.LOG_W), 0.0)
        self.times = np.full(LOG_TICKS, 0, dtype=np.int64)
        self.ctl = np.zeros(CTL_SIZE, dtype=np.int64)
        self.ctl[CT_PERIOD] = int(round(cfg[M.C_DT] * 1e9))
        self.ctl[CT_SPIN] = int(spin_us * 1e3)
        self.scheduling = ""
        self.device_clock = 0.0
        self.depth = Depth(port.axis) if port is not None else None
        self.lateral = Lateral(port.axis, cfg[M.C_DT], cfg[M.C_BC]) if port is not None else None
        self.sample: DeviceSample | None = None  # the port's last reading
        self._thread: threading.Thread | None = None

    # -- the simulation's side -------------------------------------------------------------------
    def refresh(self, model: np.ndarray) -> None:
        """Hand the loop a new model (seqlock writer: odd while writing)."""
        self.seq[0] += 1
        self.mailbox[:] = model
        self.seq[0] += 1

    @property
    def ticks(self) -> int:
        return int(self.ctl[CT_TICKS])

    def latest(self) -> np.ndarray:
        """The last tick's log row (zeros before the first)."""
        k = self.ticks
        return self.log[(k - 1) % LOG_TICKS].copy() if k else np.zeros(D.LOG_W)

    def rows(self, start: int = 0) -> np.ndarray:
        """The logged ticks from `start` on (those still in the ring), oldest first."""
        k = self.ticks
        start = max(start, k - LOG_TICKS, 0)
        idx = np.arange(start, k) % LOG_TICKS
        return self.log[idx]

    # -- running ----------------------------------------------------------------------------------
    def args(self) -> tuple:
        return (self.cfg, self.mailbox, self.seq, self.scratch_model, self.model, self.state, self.traj, self.hand,
                self.log)  # fmt: skip

    def advance(self, until: int) -> None:
        """Lockstep: run the ticks up to `until` now."""
        run_ticks(*self.args(), self.ctl, int(until))

    def start(self, limit: int = 0) -> None:
        """Start the loop's thread ("kernel" or "python" mode); `limit`: stop after that many ticks."""
        if self.mode == "lockstep" or self._thread is not None:
            return
        self.ctl[CT_LIMIT] = limit
        target = self._run_kernel if self.mode == "kernel" else self._run_python
        self._thread = threading.Thread(target=target, name="chainsim-servo", daemon=True)
        self._thread.start()

    def _run_kernel(self) -> None:
        self.scheduling = realtime_thread()
        servo_loop(*self.args(), self.times, self.ctl)

    def _run_python(self) -> None:
        self.scheduling = realtime_thread() + "; the GIL every tick"
        period = self.ctl[CT_PERIOD] / 1e9
        deadline = time.monotonic()
        args, ctl = self.args(), self.ctl
        while ctl[CT_STOP] == 0 and (ctl[CT_LIMIT] == 0 or ctl[CT_TICKS] < ctl[CT_LIMIT]):
            deadline += period
            wait = deadline - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            t = time.monotonic()
            late = t - deadline
            if late >= period:
                ctl[CT_MISSED] += int(late // period)
                deadline += (late // period) * period
            self.times[ctl[CT_TICKS] % LOG_TICKS] = time.monotonic_ns()
            if self.port is None:
                run_ticks(*args, ctl, ctl[CT_TICKS] + 1)
            else:
                self._port_tick()

    def _port_tick(self) -> None:
        port, depth = self.port, self.depth
        if port is None or depth is None:  # stopped
            return
        self.device_clock = port.clock()  # the device's own time at this tick
        sample = port.read()
        self.sample = sample  # the stylus's pose, for the needle's heading (the App's thread reads it)
        x_h = depth(sample, self.model[M.M_PLACED] != 0.0)
        f = port_tick(*self.args()[:6], self.log, self.ctl, x_h)
        out = -f * depth.axis  # on the hand: against the insertion when positive
        if self.lateral is not None:  # in tissue the needle holds the hand on its line
            out = out + self.lateral(sample.position, depth.ref, self.embedded())
            size = float(np.linalg.norm(out))
            if size > self.cfg[M.C_FMAX]:
                out *= self.cfg[M.C_FMAX] / size
        port.write(out)

    def embedded(self) -> float:
        """mm of the needle in tissue: past the first boundary it punctured (0 before the skin gives)."""
        if self.state[M.S_P] < 1 or self.model[M.M_NC] < 1:
            return 0.0
        return max(float(self.state[M.S_XT] - self.model[M.M_HEAD + M.X_DEPTH]), 0.0)

    def wait(self, timeout: float | None = None) -> None:
        """Until the loop ends (its tick limit), at most `timeout` seconds."""
        if self._thread is not None:
            self._thread.join(timeout)

    def stop(self) -> None:
        self.ctl[CT_STOP] = 1
        if self._thread is not None:
            self._thread.join(2.0)
            self._thread = None
        if self.port is not None:
            self.port.write(np.zeros(3))
            self.port.close()
            self.port = None

    def stats(self, skip: int = 0) -> dict:
        """Tick periods (ms) over the ticks after the first `skip`: median, p99, p99.9, worst; missed
        deadlines; ticks."""
        k = self.ticks
        t = self.times[np.arange(max(skip, k - LOG_TICKS), k) % LOG_TICKS]
        d = np.diff(t) / 1e6 if len(t) > 1 else np.zeros(1)
        return {
            "ticks": k,
            "missed_ticks": int(self.ctl[CT_MISSED]),
            "period_ms_p50": float(np.median(d)),
            "period_ms_p99": float(np.percentile(d, 99)),
            "period_ms_p999": float(np.percentile(d, 99.9)),
            "period_ms_max": float(d.max()),
            "late_ticks_2ms": int((d > 2.0).sum()),
        }


def warm() -> None:
    """Compile (or load) every haptics kernel once, with the argument types the app passes."""
    cfg = M.new_cfg()
    model = M.new_model()
    M.set_crossings(model, [(0.0, 10.0, 0.2, 1.0, 0.3, 0.02, 0.01, 2e-4, 0.0)])
    model[M.M_PLACED], model[M.M_GEN], model[M.M_WALL] = 1.0, 1.0, 8.0
    traj = D.scripted([(0.0, -1.0), (0.01, 9.0)])
    D.run(cfg, model, [0], traj)
    servo = Servo(cfg, traj, D.new_hand(-1.0), mode="lockstep")
    servo.refresh(model)
    servo.advance(5)
    servo.ctl[CT_LIMIT] = 7
    servo_loop(*servo.args(), servo.times, servo.ctl)  # two 1 ms ticks past the five
    port_tick(*servo.args()[:6], servo.log, servo.ctl, 1.0)
    scratch()

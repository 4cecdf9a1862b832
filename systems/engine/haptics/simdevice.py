"""The simulated device: a hand that follows a trajectory through a spring and a mass, ticked with the servo at 1 kHz.

With no hardware, the device is this: a trajectory (the depth the trainee means the needle to be at,
per tick: scripted keyframes joined by minimum-jerk moves, or a recorded attempt's hand depths) pulls a
hand of mass m through a spring k and damper b (the arm's own stiffness), and the device's force acts on
that mass. Each tick (`device_tick`): the servo reads the hand's depth, the contact model answers with a
force (chainsim.systems.engine.haptics.model.contact_tick), the force pushes the hand for the tick
(zero-order hold, as a real device renders it) and the hand moves (semi-implicit Euler). Every tick is
logged (the L_* columns: tick, the trajectory's depth, hand, tool, force, crossings passed, events,
wall). `simulate` runs a whole trajectory in lockstep, with model refreshes at given
ticks, in one compiled loop: the same inputs give the same log, byte for byte, which is what the tests
and a headless run rely on; the servo thread (chainsim.systems.engine.haptics.servo) runs the same
`device_tick` against the wall clock.

Units: mm, N, s; mass in N s^2/mm (1 kg = 1e-3). The default hand (0.15 kg, 0.5 N/mm, damping ratio
0.7) is a hand holding a pen-like stylus: stiff enough to push through skin, soft enough to be stopped.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
from numba import njit

from chainsim.systems.engine.haptics import model as M

# hand: x, v, mass, stiffness, damping, trajectory tick, whether the trajectory plays before placement
H_X, H_V, H_M, H_K, H_B, H_T, H_FREE = range(7)
HAND_SIZE = 8

# one row per tick
L_TICK, L_REF, L_HAND, L_TOOL, L_FORCE, L_PASSED, L_EVENT, L_WALL = range(8)
LOG_W = 8


def new_hand(
    x0: float, mass_kg: float = 0.15, stiffness: float = 0.5, zeta: float = 0.7, free: bool = True
) -> np.ndarray:
    """A hand at depth x0 at rest; `free`: the trajectory plays from the first tick, else from placement."""
    m = mass_kg * 1e-3
    h = np.zeros(HAND_SIZE)
    h[H_X], h[H_M], h[H_K] = x0, m, stiffness
    h[H_B] = 2.0 * zeta * np.sqrt(stiffness * m)
    h[H_FREE] = 1.0 if free else 0.0
    return h


@njit(cache=True, nogil=True)
def device_tick(cfg, model, state, traj, hand, log, row, tick):
    """One tick: the servo's force for the hand where it is, the hand moved by it for the tick; logged in
    log[row]. Returns the force (N, positive resisting insertion)."""
    dt = cfg[M.C_DT]
    n = traj.shape[0]
    i = min(int(hand[H_T]), n - 1)
    x_ref = traj[i]
    v_ref = 0.0 if i == 0 or int(hand[H_T]) >= n else (traj[i] - traj[i - 1]) / dt
    x_h = hand[H_X]
    f = M.contact_tick(cfg, model, state, x_h)
    log[row, L_TICK] = tick
    log[row, L_REF] = x_ref
    log[row, L_HAND] = x_h
    log[row, L_TOOL] = state[M.S_XT]
    log[row, L_FORCE] = f
    log[row, L_PASSED] = state[M.S_P]
    log[row, L_EVENT] = state[M.S_EVENT]
    log[row, L_WALL] = state[M.S_WALL]
    a = (hand[H_K] * (x_ref - x_h) + hand[H_B] * (v_ref - hand[H_V]) - f) / hand[H_M]
    hand[H_V] += a * dt
    hand[H_X] += hand[H_V] * dt
    if hand[H_FREE] != 0.0 or model[M.M_PLACED] != 0.0:
        hand[H_T] += 1.0
    return f


@njit(cache=True, nogil=True)
def simulate(cfg, models, at, model, state, traj, hand, log):
    """len(log) ticks in lockstep; models[j] is taken (apply_model) at tick at[j] (ascending)."""
    j = 0
    for k in range(log.shape[0]):
        while j < at.shape[0] and at[j] <= k:
            M.apply_model(models[j], model, state)
            j += 1
        device_tick(cfg, model, state, traj, hand, log, k, k)


def run(cfg, models, at, traj, hand=None, ticks: int | None = None) -> np.ndarray:
    """`simulate` from a fresh state: the log (ticks x LOG_W). models: (n, MODEL_SIZE) taken at ticks `at`."""
    models = np.ascontiguousarray(np.atleast_2d(models), dtype=np.float64)
    at = np.ascontiguousarray(at, dtype=np.int64)
    traj = np.ascontiguousarray(traj, dtype=np.float64)
    hand = new_hand(float(traj[0])) if hand is None else hand.copy()
    log = np.zeros((len(traj) if ticks is None else ticks, LOG_W))
    simulate(cfg, models, at, M.new_model(), M.new_state(), traj, hand, log)
    return log


# -- trajectories ------------------------------------------------------------------------------------


def scripted(keys, dt: float = 1e-3) -> np.ndarray:
    """Depth per tick through keyframes [(t_s, depth_mm), ...] (times ascending from 0), each move a
    minimum-jerk one (no step in speed or acceleration at the keyframes), held after the last."""
    keys = [(float(t), float(x)) for t, x in keys]
    if not keys or keys[0][0] != 0.0 or any(b[0] <= a[0] for a, b in zip(keys, keys[1:])):
        raise ValueError("keyframes: (t_s, depth_mm) pairs with times rising from 0")
    n = int(round(keys[-1][0] / dt)) + 1
    t = np.arange(n) * dt
    out = np.full(n, keys[-1][1])
    for (t0, x0), (t1, x1) in zip(keys, keys[1:]):
        sel = (t >= t0) & (t < t1)
        s = (t[sel] - t0) / (t1 - t0)
        out[sel] = x0 + (x1 - x0) * s**3 * (10.0 - 15.0 * s + 6.0 * s * s)
    return out


def insertion(depth: float, speed: float = 10.0, start: float = -3.0, wait: float = 1.5, hold: float = 1.0):
    """Keyframes of one insertion: wait at `start`, in to `depth` at about `speed` mm/s, hold, out twice as fast."""
    t_in = wait + max((depth - start) / speed * 1.875, 0.1)  # a minimum-jerk move peaks at 1.875x its mean speed
    t_hold = t_in + hold
    return [(0.0, start), (wait, start), (t_in, depth), (t_hold, depth), (t_hold + (t_in - wait) / 2, start)]


def load(path: str, dt: float = 1e-3) -> np.ndarray:
    """A trajectory file: CSV with `t_s,depth_mm` keyframes (scripted), or a device attempt's haptic trace
    (its `hand_mm` column, one row per tick: the attempt played again). ValueError names what is wrong."""
    p = Path(path)
    try:
        with p.open(newline="") as f:
            rows = list(csv.DictReader(f))
    except OSError as e:
        raise ValueError(f"trajectory {path}: cannot read it ({e.strerror})") from None
    if not rows:
        raise ValueError(f"trajectory {path}: no rows (expected a header t_s,depth_mm or a haptic trace)")
    try:
        if "hand_mm" in rows[0]:
            return np.array([float(r["hand_mm"]) for r in rows])
        if {"t_s", "depth_mm"} <= set(rows[0]):
            return scripted([(float(r["t_s"]), float(r["depth_mm"])) for r in rows], dt)
    except (TypeError, ValueError) as e:
        raise ValueError(f"trajectory {path}: {e}") from None
    raise ValueError(f"trajectory {path}: expected columns t_s,depth_mm (keyframes) or hand_mm (a haptic trace)")

"""The needle's local contact model and one servo tick: the tool, coupled to the hand, against the tissue.

What the 60 Hz tissue simulation knows about the needle's line (chainsim.systems.procedures.needle.tissue)
is copied each frame into a flat float64 array, the *model* (layout below): the boundaries the line
crosses in order (depth from the entry, the tissue behind each along the line, the punch stiffness of
the layer entered, its puncture force, cutting force and friction per mm), which of them are holes the
needle passes freely, and the depth of the wall (bone or the target) the line meets. The servo keeps
its own *state* array: the tool's depth, how many boundaries it has passed, which are holes now.

One tick (`contact_tick`), at 1 kHz: the hand's depth x_h comes in, the tool (the needle, depth x) is
pulled towards it by the virtual coupling, a spring-damper (Colgate, Stanley and Brown, 1995),

    R = k_c (x_h - x) + b_c (v_h - v),     v_h, v the backward differences over the tick,

and the tool is quasi-static (no mass): it moves only as far as the tissue lets the coupling pull it.
The tissue's force on the tool is the simulation's own law (chainsim.systems.engine.needle_force,
Okamura et al. 2004): a boundary pressed by `tent` mm pushes back press_force(k, tent, room); the tip
cuts through the layer it is in at that layer's cutting force while it advances; the shaft rubs with
L (C + b |v|) per layer while it slides and holds with up to L D while it sticks (Coulomb's static
friction, the Karnopp band's limit). Forward, the tip's resistance is the larger of the cutting force
and the press of the next boundary (the tip stops cutting as the boundary ahead takes the load: the
simulation switches from one to the other at the boundary; here the hand feels no step there). So:

- stick: the tool stays while R, with the tool still, lies within [E - S, max(cut, E) + S] (E the press,
  S the shaft's static friction): the hand feels the coupling spring, continuous;
- slide: otherwise the tool moves to where R balances the sliding resistance, found by bisection on a
  bracket that provably holds the balance (44 halvings: 1e-12 mm);
- puncture: where the balance lies at or past the tent at which the pressed boundary gives, it gives in
  this tick, the tool goes on through and the balance is found again: the force drops in the tick the
  tip reaches the puncture force, not a frame later; a hole (re-entry) passes without pressing;
- exit: withdrawn to a boundary's depth, the tool is back in front of it;
- wall: the tool never passes the wall's depth; held there, the hand feels the coupling alone, a
  spring-damper wall whose force grows with the push ("the needle cannot pass, and the force says so").

The coupling's damping b_c > k_c T / 2 keeps the sampled wall passive (Colgate and Schenkel 1997: a
zero-order-held spring K sampled at T gives back K T / 2 per unit of velocity squared; the damper on
the backward difference takes it away). The force is clipped to the device's largest.

All kernels are nopython, nogil and cached; the same arithmetic written plainly is
chainsim.systems.engine.haptics.reference, against which tests check these.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from chainsim.systems.engine.needle_force import press_force

# -- cfg: the servo's settings ---------------------------------------------------------------------
C_KC = 0  # coupling stiffness, N/mm
C_BC = 1  # coupling damping, N s/mm
C_DT = 2  # tick, s
C_FMAX = 3  # largest force the device renders, N
CFG_SIZE = 4

# -- model: what the simulation refreshes ----------------------------------------------------------
M_GEN = 0  # generation: a new one when the crossings are computed again (the needle turned, placed, reset)
M_PLACED = 1  # 1 while the needle is placed on the skin (else the tool follows the hand, no force)
M_NC = 2  # crossings in use
M_WALL = 3  # depth of the wall (bone, target) along the line, mm; inf: none
M_PSIM = 4  # crossings the simulation has passed (shown, not used by the tick)
M_HEAD = 8
# one row per crossing, deepening: where it is, the layer it enters
X_DEPTH, X_ROOM, X_K, X_THR, X_CUT, X_STATIC, X_DYN, X_VISC, X_HOLE = range(9)
CW = 9
MAXC = 32
MODEL_SIZE = M_HEAD + MAXC * CW

# -- state: the servo's own --------------------------------------------------------------------------
S_XT = 0  # tool depth, mm
S_XH = 1  # hand depth last tick, mm
S_VT = 2  # tool speed, mm/s
S_P = 3  # crossings passed
S_GEN = 4  # model generation the state belongs to
S_WALL = 5  # 1 while the tool is held at the wall
S_EVENT = 6  # this tick's events (bits below)
S_EVC = 7  # the crossing of the last puncture, exit or re-entry
S_R = 8  # coupling force, N, positive resisting insertion (before clipping)
S_STARTED = 9  # 0 until the first tick
S_MOVE = 10  # this tick: 0 stuck, +1 slid in, -1 slid out
S_HOLE0 = 16  # one flag per crossing: a hole (passes freely)
STATE_SIZE = S_HOLE0 + MAXC

EV_PUNCTURE = 1
EV_EXIT = 2
EV_WALL = 4  # the tool came to the wall this tick
EV_REENTRY = 8

BISECTIONS = 44


def new_cfg(k_c: float = 0.6, b_c: float = 0.0006, dt: float = 1e-3, f_max: float = 3.3) -> np.ndarray:
    """Servo settings: coupling k_c N/mm and b_c N s/mm, tick dt s, device force limit f_max N. Refused
    (ValueError) where the sampled coupling would not be passive: b_c must exceed k_c dt / 2."""
    if not (k_c > 0 and dt > 0 and f_max > 0 and b_c > k_c * dt / 2):
        raise ValueError(
            f"coupling k_c={k_c} N/mm, b_c={b_c} N s/mm at dt={dt} s: need k_c, dt > 0 and b_c > k_c dt / 2"
        )
    cfg = np.zeros(CFG_SIZE)
    cfg[C_KC], cfg[C_BC], cfg[C_DT], cfg[C_FMAX] = k_c, b_c, dt, f_max
    return cfg


def new_model() -> np.ndarray:
    """An empty model: nothing placed, no crossings, no wall."""
    m = np.zeros(MODEL_SIZE)
    m[M_WALL] = np.inf
    return m


def new_state() -> np.ndarray:
    return np.zeros(STATE_SIZE)


def set_crossings(model: np.ndarray, rows) -> None:
    """Write crossings, each (depth, room, k, puncture_N, cutting_N, static, dyn, visc, hole), deepening."""
    rows = np.asarray(rows, dtype=np.float64).reshape(-1, CW)
    if len(rows) > MAXC:
        raise ValueError(f"{len(rows)} crossings along the needle's line; the model holds {MAXC}")
    model[M_HEAD : M_HEAD + MAXC * CW] = 0.0
    model[M_HEAD : M_HEAD + len(rows) * CW] = rows.ravel()
    model[M_NC] = len(rows)


# -- the tissue along the line ---------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _row(i):
    return M_HEAD + i * CW


@njit(cache=True, nogil=True)
def elastic(model, state, p, x):
    """Press (N) of the first boundary not passed, with the tip at x; 0 when none is pressed or it is a hole."""
    if p >= int(model[M_NC]) or state[S_HOLE0 + p] != 0.0:
        return 0.0
    b = _row(p)
    return press_force(model[b + X_K], x - model[b + X_DEPTH], model[b + X_ROOM])


@njit(cache=True, nogil=True)
def shaft(model, p, x, col):
    """Sum over the passed crossings of the shaft length in the layer each enters (mm) times column `col`."""
    total = 0.0
    for i in range(p):
        b = _row(i)
        d = model[b + X_DEPTH]
        end = model[_row(i + 1) + X_DEPTH] if i + 1 < p else x
        length = min(end, x, d + model[b + X_ROOM]) - d
        if length > 0.0:
            total += length * model[b + col]
    return total


@njit(cache=True, nogil=True)
def cutting(model, p, x):
    """Cutting force of the layer the tip is in (0 outside the tissue or past its far side)."""
    if p == 0:
        return 0.0
    b = _row(p - 1)
    if x > model[b + X_DEPTH] + model[b + X_ROOM]:
        return 0.0
    return model[b + X_CUT]


@njit(cache=True, nogil=True)
def resistance(model, state, p, x, speed, s):
    """The tissue's force on the tool (N, positive resisting insertion) sliding at `speed` mm/s in
    direction s (+1 in, -1 out): forward the tip's larger of cutting and press, then the shaft's friction."""
    e = elastic(model, state, p, x)
    fric = shaft(model, p, x, X_DYN) + speed * shaft(model, p, x, X_VISC)
    if s > 0:
        return max(cutting(model, p, x), e) + fric
    return e - fric


# -- one tick ----------------------------------------------------------------------------------------


@njit(cache=True, nogil=True)
def _balance(cfg, model, state, p, x0, x_h, v_h, s, wall):
    """Where the tool sliding from x0 in direction s balances the coupling (bisection), or the wall."""
    kc, bc, dt = cfg[C_KC], cfg[C_BC], cfg[C_DT]
    c = kc + bc / dt
    push0 = kc * (x_h - x0) + bc * v_h
    # at x0 + (push0 - E(x0)) / c the coupling is down to E(x0), which the tissue there matches or beats
    far = x0 + (push0 - elastic(model, state, p, x0)) / c
    lo, hi = (x0, far) if s > 0 else (far, x0)
    if s > 0 and hi >= wall:
        hi = wall
        if push0 - c * (wall - x0) - resistance(model, state, p, wall, (wall - x0) / dt, 1.0) >= 0.0:
            return wall
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        g = push0 - c * (mid - x0) - resistance(model, state, p, mid, abs(mid - x0) / dt, s)
        if g >= 0.0:
            lo = mid
        else:
            hi = mid
    return lo if s > 0 else hi


@njit(cache=True, nogil=True)
def _settle(cfg, model, state, p, x0, x_h, v_h, wall):
    """The tool's depth this tick with p crossings passed: stuck at x0, or slid to the balance."""
    push0 = cfg[C_KC] * (x_h - x0) + cfg[C_BC] * v_h
    e0 = elastic(model, state, p, x0)
    hold = shaft(model, p, x0, X_STATIC)
    if push0 > max(cutting(model, p, x0), e0) + hold:
        state[S_MOVE] = 1.0
        return _balance(cfg, model, state, p, x0, x_h, v_h, 1.0, wall)
    if push0 < e0 - hold:
        state[S_MOVE] = -1.0
        return _balance(cfg, model, state, p, x0, x_h, v_h, -1.0, wall)
    state[S_MOVE] = 0.0
    return x0


@njit(cache=True, nogil=True)
def _passes(model, state, p, x):
    """Whether the tool at x goes through crossing p this tick: 1 puncture, 2 through a hole, 0 not."""
    if p >= int(model[M_NC]):
        return 0
    b = _row(p)
    if x <= model[b + X_DEPTH]:
        return 0
    if state[S_HOLE0 + p] != 0.0:
        return 2
    if press_force(model[b + X_K], x - model[b + X_DEPTH], model[b + X_ROOM]) >= model[b + X_THR]:
        return 1
    return 0


@njit(cache=True, nogil=True)
def _move(cfg, model, state, x0, x_h, v_h):
    """The tool's new depth: settled, then through every boundary it punctures (settled again after each)
    and back out of those it is withdrawn from. Sets S_P and the tick's events."""
    wall = model[M_WALL]
    nc = int(model[M_NC])
    p = int(state[S_P])
    x = _settle(cfg, model, state, p, x0, x_h, v_h, wall)
    for _ in range(nc):
        through = _passes(model, state, p, x)
        if through == 0:
            break
        state[S_EVENT] = float(int(state[S_EVENT]) | (EV_PUNCTURE if through == 1 else EV_REENTRY))
        state[S_EVC] = p
        state[S_HOLE0 + p] = 1.0  # a punctured boundary keeps its hole
        p += 1
        x = _settle(cfg, model, state, p, x0, x_h, v_h, wall)
    while p > 0 and x <= model[_row(p - 1) + X_DEPTH]:
        p -= 1
        state[S_EVENT] = float(int(state[S_EVENT]) | EV_EXIT)
        state[S_EVC] = p
    state[S_P] = p
    return x


@njit(cache=True, nogil=True)
def contact_tick(cfg, model, state, x_h):
    """One servo tick with the hand at depth x_h (mm): moves the tool, returns the force for the device
    (N along the needle, positive resisting insertion, clipped to cfg[C_FMAX])."""
    dt = cfg[C_DT]
    wall = model[M_WALL]
    if state[S_STARTED] == 0.0:
        state[S_STARTED] = 1.0
        state[S_XH] = x_h
        state[S_XT] = min(x_h, wall)
    v_h = (x_h - state[S_XH]) / dt
    state[S_XH] = x_h
    state[S_EVENT] = 0.0
    x0 = state[S_XT]
    if model[M_PLACED] == 0.0:
        x, r = x_h, 0.0  # not on the skin: the tool goes with the hand
        state[S_P] = 0.0
        state[S_MOVE] = 0.0
    else:
        x0 = min(x0, wall)  # a refresh may have brought the wall nearer
        x = _move(cfg, model, state, x0, x_h, v_h)
        r = cfg[C_KC] * (x_h - x) + cfg[C_BC] * (v_h - (x - x0) / dt)
    at_wall = model[M_PLACED] != 0.0 and x >= wall
    if at_wall and state[S_WALL] == 0.0:
        state[S_EVENT] = float(int(state[S_EVENT]) | EV_WALL)
    state[S_WALL] = 1.0 if at_wall else 0.0
    state[S_VT] = (x - x0) / dt
    state[S_XT] = x
    state[S_R] = r
    f_max = cfg[C_FMAX]
    return min(max(r, -f_max), f_max)


@njit(cache=True, nogil=True)
def apply_model(new, model, state):
    """Take a model the simulation refreshed: the same generation keeps the servo's own puncture state
    (it is ahead of the frame) and learns the simulation's holes; a new one starts over, the crossings
    behind the tool counted as passed."""
    same = new[M_GEN] == state[S_GEN]
    model[:] = new
    nc = int(new[M_NC])
    if same:
        for i in range(nc):
            if new[_row(i) + X_HOLE] != 0.0:
                state[S_HOLE0 + i] = 1.0
        return
    state[S_GEN] = new[M_GEN]
    for i in range(MAXC):
        state[S_HOLE0 + i] = new[_row(i) + X_HOLE] if i < nc else 0.0
    p = 0
    while p < nc and state[S_XT] > new[_row(p) + X_DEPTH]:
        p += 1
    state[S_P] = p

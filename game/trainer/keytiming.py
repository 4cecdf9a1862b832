"""When a seat's key events land in simulated time: the window's, a browser session's, and the input
held while the kernels compile (chainsim.game.trainer.compiling) alike.

A scene reads a key once a step. Device events come between steps, and a press and its release that
arrive before a step ran would both be gone before anything read them; taps that arrive together (a
network hands over a burst at once, held input is given all at once) would be one turn of a dial for
the lot. `key_times` spaces them so that every press is seen by a step of its own (thesis 3.3.4: the
controller's keys turn the needle a step per press).
"""

from __future__ import annotations


def key_times(keys: dict[str, tuple[float, float]], key: str, pressed: bool, now: float, dt: float) -> tuple[float]:
    """The simulated time a key event from the page lands at, `keys` updated. A key pressed and released
    before a step ran is held for one step, as in the window. Presses of one key that arrive together
    (the network hands over a burst of taps at once) land two steps apart each, so every tap is one turn
    of a dial, not one turn for the lot."""
    if pressed:
        at = max(now, keys.get(key, (now, now))[1])
        keys[key] = (at, at)
        return (at,)
    down, _ = keys.get(key, (now - dt, now))
    if down >= now:  # released before a step ran with it held: up a step later, the next press a step after
        keys[key] = (down, down + 2 * dt)
        return (down + dt,)
    return (now,)

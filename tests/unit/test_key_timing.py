"""Key timing (chainsim.game.trainer.keytiming.key_times: the browser trainer's, the window's, the held input's):
a tap held for one step, a burst of taps of one key that arrives at once spread a step apart each, a held
key released when the page says so."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from chainsim.game.trainer.keytiming import key_times

DT = 1 / 120


def _held_steps(events: list[tuple[float, bool]], steps: int) -> list[bool]:
    """Whether the key is down during each step (events applied at the start of their step, in order)."""
    down, out = False, []
    for k in range(steps):
        t = k * DT
        for at, pressed in events:
            if abs(at - t) < 1e-9:
                down = pressed
        out.append(down)
    return out


@given(st.integers(1, 12))
def test_taps_that_arrive_together_are_each_a_press_of_their_own(n):
    keys: dict = {}
    events = []
    for _ in range(n):  # n press-release pairs, all before the next step runs
        events.append((*key_times(keys, "left", True, 0.0, DT), True))
        events.append((*key_times(keys, "left", False, 0.0, DT), False))
    presses = [at for at, pressed in events if pressed]
    releases = [at for at, pressed in events if not pressed]
    assert len(set(presses)) == n and presses == sorted(presses)
    for p, r in zip(presses, releases, strict=True):
        assert abs(r - p - DT) < 1e-12  # held for exactly one step
    held = _held_steps(events, 2 * n + 2)
    # every press is seen: n separate runs of one step down
    runs = sum(1 for k in range(len(held)) if held[k] and (k == 0 or not held[k - 1]))
    assert runs == n


def test_a_held_key_is_released_when_the_page_says():
    keys: dict = {}
    assert key_times(keys, "i", True, 1.0, DT) == (1.0,)
    assert key_times(keys, "i", False, 1.5, DT) == (1.5,)  # held for half a second: up at once
    assert key_times(keys, "i", True, 2.0, DT) == (2.0,)  # a later press lands at once

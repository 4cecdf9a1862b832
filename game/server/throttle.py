"""Password-guess throttling for the records server's two sign-ins (``POST /api/login`` and the form).

Failed sign-ins are counted per account name and per client address, in the server process. Past a
few free failures each key must wait before its next try, the wait doubling with every further
failure: an address up to ``ADDRESS_MAX_WAIT_S`` (an attacker's own address may be slowed for long),
an account only up to ``ACCOUNT_MAX_WAIT_S``, so that guesses against a real user's name from many
addresses slow them down without locking them out for more than half a minute. A throttled try is
answered 429 with Retry-After before the password is looked at, so a flood of guesses costs the
server no password hashing and other requests keep their speed. A right password clears its
account's count (not the address's: signing in to one's own account must not buy more guesses).
Counts of keys idle for ``FORGET_S`` are dropped.

The address is the connection's own (the socket's peer). Only behind a proxy named with ``chainsim
serve --trust-proxy ADDR`` is it the client that proxy names in X-Forwarded-For (uvicorn puts it in
``request.client``): believed from anyone, the header would let a guesser pick a new address per try.
"""

from __future__ import annotations

import math
import threading
import time

from chainsim.game.server.auth import HTTPError

#: failures a key may have before it must wait
ACCOUNT_FREE, ADDRESS_FREE = 5, 20
#: the longest wait between two tries (seconds)
ACCOUNT_MAX_WAIT_S, ADDRESS_MAX_WAIT_S = 30.0, 900.0
#: a key with no failure for this long starts again from zero
FORGET_S = 3600.0


class Throttle:
    """Failure counts and the next time each key may try; thread-safe; ``clock`` for tests."""

    def __init__(self, clock=time.monotonic) -> None:
        self.clock = clock
        self._lock = threading.Lock()
        self._keys: dict[tuple[str, str], tuple[int, float, float]] = {}  # key -> (failures, next try, last)

    def _wait(self, key: tuple[str, str], now: float) -> float:
        failures, next_try, last = self._keys.get(key, (0, 0.0, now))
        if now - last > FORGET_S:
            self._keys.pop(key, None)
            return 0.0
        return max(0.0, next_try - now)

    def wait_s(self, name: str, address: str) -> float:
        """Seconds before a sign-in as ``name`` from ``address`` may be tried (0: now)."""
        now = self.clock()
        with self._lock:
            return max(self._wait(("account", name), now), self._wait(("address", address), now))

    def failed(self, name: str, address: str) -> None:
        now = self.clock()
        with self._lock:
            if len(self._keys) > 100_000:  # a flood of made-up names: forget the idle ones first
                self._keys = {k: v for k, v in self._keys.items() if now - v[2] <= FORGET_S}
            for key, free, cap in (
                (("account", name), ACCOUNT_FREE, ACCOUNT_MAX_WAIT_S),
                (("address", address), ADDRESS_FREE, ADDRESS_MAX_WAIT_S),
            ):
                failures, _, last = self._keys.get(key, (0, 0.0, now))
                failures = 1 if now - last > FORGET_S else failures + 1
                wait = 0.0 if failures <= free else min(cap, 2.0 ** (failures - free - 1))
                self._keys[key] = (failures, now + wait, now)

    def succeeded(self, name: str) -> None:
        with self._lock:
            self._keys.pop(("account", name), None)


def retry_after(wait_s: float) -> str:
    """The Retry-After header value: whole seconds, at least 1."""
    return str(max(1, math.ceil(wait_s)))


def guarded(request, name) -> tuple[str, str]:
    """``(name key, address)`` of a sign-in; HTTPError 429 (with Retry-After) while either must wait."""
    key = name.strip()[:64] if isinstance(name, str) else ""
    address = request.client.host if request.client else ""  # the peer, or what a trusted proxy names
    wait = request.app.state.throttle.wait_s(key, address)
    if wait > 0:
        after = retry_after(wait)
        raise HTTPError(429, f"too many failed sign-ins; try again in {after} s", {"Retry-After": after})
    return key, address

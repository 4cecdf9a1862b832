"""Uploads per account: a token bucket per signed-in account, so one trainee's flood cannot fill the queue.

Each account may file ``per_minute`` uploads a minute on average, ``burst`` at once (the simulator's
offline queue sends its waiting attempts together). Past that an upload is answered 429 with
Retry-After: the seconds until the next one is allowed; the simulator's queue keeps the attempt and
sends it again then. Counts live in the server process (one process serves); idle accounts are
forgotten after an hour.
"""

from __future__ import annotations

import math
import threading
import time

from chainsim.game.server.auth import HTTPError

#: uploads a minute per account on average, and at once
DEFAULT_PER_MINUTE = 6.0
DEFAULT_BURST = 20
FORGET_S = 3600.0


class UploadRate:
    """Token buckets by account id; ``take(account)`` or HTTPError 429; ``clock`` for tests."""

    def __init__(self, per_minute: float = DEFAULT_PER_MINUTE, burst: int = DEFAULT_BURST, clock=time.monotonic):
        if not 0.1 <= per_minute <= 10000 or not 1 <= burst <= 10000:
            raise ValueError("uploads per minute must be from 0.1 to 10000 and the burst from 1 to 10000")
        self.rate = per_minute / 60.0
        self.burst = float(burst)
        self.clock = clock
        self._lock = threading.Lock()
        self._buckets: dict[int, tuple[float, float]] = {}  # account -> (tokens, when)

    def take(self, account: int) -> None:
        """Spend one upload of ``account``'s allowance, or raise 429 with the wait in Retry-After."""
        now = self.clock()
        with self._lock:
            tokens, when = self._buckets.get(account, (self.burst, now))
            tokens = min(self.burst, tokens + (now - when) * self.rate)
            if tokens < 1.0:
                wait = math.ceil((1.0 - tokens) / self.rate)
                self._buckets[account] = (tokens, now)
                raise HTTPError(
                    429,
                    f"too many uploads from this account: at most {self.rate * 60:g} a minute "
                    f"({self.burst:g} at once); try again in {wait} s",
                    headers={"Retry-After": str(wait)},
                )
            self._buckets[account] = (tokens - 1.0, now)
            if len(self._buckets) > 10000:
                self._buckets = {k: v for k, v in self._buckets.items() if now - v[1] < FORGET_S}

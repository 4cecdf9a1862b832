"""Pacing an App by the wall clock in whole fixed steps, so a window session replays exactly.

A window frame lasts whatever the machine allows (8 ms, 40 ms, a 300 ms stall); the App must not
care. `FixedStepper.advance(wall_dt)` turns the wall time since the previous frame into whole fixed
steps and runs each as its own `App.update(dt)` - input released, one simulation step, procedure -
exactly as a headless run or `chainsim replay` does, one step per update. The render system draws
only after the last of them (`RenderTarget.hold`). A recording made in the window therefore replays
to the same digest whatever the frame times were (the test drives this class with uneven ones).

Time that does not fill a step is carried to the next frame; at most MAX_STEPS run per frame, so a
long stall slows the simulation down instead of freezing the window while it catches up.
"""

from __future__ import annotations

MAX_WALL_DT = 0.1  # seconds of one frame counted at most (a stall is not made up for)
MAX_STEPS = 12


class FixedStepper:
    def __init__(self, app, target=None):
        self.app = app
        self.target = target  # RenderTarget of a window (draws after the last step), or None
        self.carry = 0.0

    def advance(self, wall_dt: float) -> int:
        """Run the whole steps `wall_dt` seconds hold (plus what earlier frames left); returns how many."""
        app = self.app
        dt = app.time.dt
        self.carry += min(max(float(wall_dt), 0.0), MAX_WALL_DT)
        n = min(int(self.carry / dt + 1e-9), MAX_STEPS)
        self.carry = min(self.carry - n * dt, dt)
        for i in range(n):
            if self.target is not None:
                self.target.hold = i < n - 1  # draw once, after the last step
            app.update(dt)
        if self.target is not None:
            self.target.hold = False
        return n


class FrameLog:
    """`chainsim play --frame-times CSV`: one row per window frame - wall seconds since the first, the
    interval since the previous frame (what the trainee sees: simulation, drawing, the buffer swap and
    waiting for the display) and the time this frame spent simulating and drawing, both in ms. Rows are
    written as they come, so a session that ends badly keeps what it measured."""

    def __init__(self, path: str | None):
        self.file = None if not path else open(path, "w", encoding="utf-8")  # noqa: SIM115 - open for the session
        self.t0: float | None = None
        if self.file is not None:
            self.file.write("t_s,interval_ms,work_ms\n")

    def add(self, t: float, interval: float, work: float) -> None:
        if self.file is None:
            return
        if self.t0 is None:
            self.t0 = t
        self.file.write(f"{t - self.t0:.4f},{interval * 1e3:.2f},{work * 1e3:.2f}\n")
        self.file.flush()

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
            self.file = None

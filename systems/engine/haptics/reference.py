"""The servo tick of chainsim.systems.engine.haptics.model written plainly: the reference for its kernels.

Same physics and the same bisection, read from lists of crossings instead of a flat array, with no
numba: tests draw models and hand paths (hypothesis) and check that the compiled tick gives the same
forces, depths, punctures and events.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from chainsim.systems.engine.haptics import model as M


@dataclass
class Crossing:
    depth: float
    room: float
    k: float
    threshold: float
    cutting: float
    static: float
    dyn: float
    visc: float
    hole: bool = False


@dataclass
class Tool:
    x: float = 0.0
    x_hand: float = 0.0
    passed: int = 0
    started: bool = False
    at_wall: bool = False
    events: int = 0
    holes: list = field(default_factory=list)


def press(k: float, tent: float, room: float) -> float:
    if tent <= 0.0:
        return 0.0
    if tent >= room:
        return math.inf
    if room == math.inf:
        return k * tent
    return k * tent * room / (room - tent)


class Reference:
    """A needle line (crossings, wall) and a tool on it, ticked by `tick(x_hand)`."""

    def __init__(self, crossings: list[Crossing], wall: float, k_c: float, b_c: float, dt: float, f_max: float):
        self.crossings, self.wall = crossings, wall
        self.k_c, self.b_c, self.dt, self.f_max = k_c, b_c, dt, f_max
        self.tool = Tool(holes=[c.hole for c in crossings])

    def elastic(self, p: int, x: float) -> float:
        if p >= len(self.crossings) or self.tool.holes[p]:
            return 0.0
        c = self.crossings[p]
        return press(c.k, x - c.depth, c.room)

    def shaft(self, p: int, x: float, what: str) -> float:
        total = 0.0
        for i in range(p):
            c = self.crossings[i]
            end = self.crossings[i + 1].depth if i + 1 < p else x
            length = min(end, x, c.depth + c.room) - c.depth
            if length > 0.0:
                total += length * getattr(c, what)
        return total

    def cutting(self, p: int, x: float) -> float:
        if p == 0:
            return 0.0
        c = self.crossings[p - 1]
        return 0.0 if x > c.depth + c.room else c.cutting

    def resistance(self, p: int, x: float, speed: float, s: float) -> float:
        e = self.elastic(p, x)
        fric = self.shaft(p, x, "dyn") + speed * self.shaft(p, x, "visc")
        return max(self.cutting(p, x), e) + fric if s > 0 else e - fric

    def balance(self, p: int, x0: float, x_h: float, v_h: float, s: float) -> float:
        c = self.k_c + self.b_c / self.dt
        push0 = self.k_c * (x_h - x0) + self.b_c * v_h
        far = x0 + (push0 - self.elastic(p, x0)) / c
        lo, hi = (x0, far) if s > 0 else (far, x0)
        if s > 0 and hi >= self.wall:
            hi = self.wall
            if push0 - c * (self.wall - x0) - self.resistance(p, self.wall, (self.wall - x0) / self.dt, 1.0) >= 0.0:
                return self.wall
        for _ in range(M.BISECTIONS):
            mid = 0.5 * (lo + hi)
            if push0 - c * (mid - x0) - self.resistance(p, mid, abs(mid - x0) / self.dt, s) >= 0.0:
                lo = mid
            else:
                hi = mid
        return lo if s > 0 else hi

    def settle(self, p: int, x0: float, x_h: float, v_h: float) -> float:
        push0 = self.k_c * (x_h - x0) + self.b_c * v_h
        e0 = self.elastic(p, x0)
        hold = self.shaft(p, x0, "static")
        if push0 > max(self.cutting(p, x0), e0) + hold:
            return self.balance(p, x0, x_h, v_h, 1.0)
        if push0 < e0 - hold:
            return self.balance(p, x0, x_h, v_h, -1.0)
        return x0

    def tick(self, x_h: float) -> float:
        t = self.tool
        if not t.started:
            t.started, t.x_hand, t.x = True, x_h, min(x_h, self.wall)
        v_h = (x_h - t.x_hand) / self.dt
        t.x_hand = x_h
        t.events = 0
        x0 = min(t.x, self.wall)
        p = t.passed
        x = self.settle(p, x0, x_h, v_h)
        for _ in range(len(self.crossings)):
            if p >= len(self.crossings) or x <= self.crossings[p].depth:
                break
            c = self.crossings[p]
            if t.holes[p]:
                t.events |= M.EV_REENTRY
            elif press(c.k, x - c.depth, c.room) >= c.threshold:
                t.events |= M.EV_PUNCTURE
            else:
                break
            t.holes[p] = True
            p += 1
            x = self.settle(p, x0, x_h, v_h)
        while p > 0 and x <= self.crossings[p - 1].depth:
            p -= 1
            t.events |= M.EV_EXIT
        t.passed = p
        at_wall = x >= self.wall
        if at_wall and not t.at_wall:
            t.events |= M.EV_WALL
        t.at_wall = at_wall
        r = self.k_c * (x_h - x) + self.b_c * (v_h - (x - x0) / self.dt)
        t.x = x
        return min(max(r, -self.f_max), self.f_max)

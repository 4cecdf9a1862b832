"""The debrief of a needle attempt: how the window colours its rows, and the geometry drawn against the
trainee's (the ideal landmark positions, the ideal needle path, the path the tip took).

The verdicts themselves (a row per metric against the pack's benchmark, the critical errors, the
outcome) are every procedure's: chainsim.systems.procedures.verdicts, which the records server's
pages read too. Plain functions on plain data, no GL and no ECS.
"""

from __future__ import annotations

import math

import numpy as np

#: debrief row tones: how the window colours a row (PASS, FAIL and PLAIN are metric rows, set in columns)
HEAD, PASS, FAIL, PLAIN, NOTE, ADVICE, CRITICAL = "head", "pass", "fail", "plain", "note", "advice", "critical"


def ideal_landmark(point, ideal_mm: float, plane, mark) -> np.ndarray:
    """Where the trainee's mark should have gone: the nearest point to `mark` at `ideal_mm` from the
    landmark's point and on its plane (both scored by 6.1.5's D and d). `plane` has `point` and unit
    `normal`, or is None; `point` may be None (only the plane is scored)."""
    q = np.asarray(mark, float)
    if point is None:
        if plane is None:
            return q
        return q - ((q - plane.point) @ plane.normal) * plane.normal
    p = np.asarray(point, float)
    if plane is None:
        d = q - p
        n = np.linalg.norm(d)
        return p if n < 1e-9 else p + ideal_mm * d / n
    nrm = np.asarray(plane.normal, float)
    h = float((p - plane.point) @ nrm)
    c = p - h * nrm  # the point's foot on the plane: centre of the circle of ideal places
    r = math.sqrt(max(ideal_mm * ideal_mm - h * h, 0.0))
    u = q - ((q - plane.point) @ nrm) * nrm - c
    n = np.linalg.norm(u)
    return c if n < 1e-9 or r == 0.0 else c + r * u / n


def thin(points, most: int = 200) -> list[list[float]]:
    """At most `most` points of a path, evenly taken, first and last kept (what an attempt stores)."""
    pts = np.asarray(points, float).reshape(-1, 3)
    if len(pts) > most:
        pts = pts[np.unique(np.linspace(0, len(pts) - 1, most).round().astype(int))]
    return [[round(float(c), 2) for c in p] for p in pts]


class PathTrace:
    """The needle tip's path while inserted, one point per half millimetre moved (an attempt's path)."""

    STEP_MM = 0.5

    def __init__(self) -> None:
        self.points: list[np.ndarray] = []
        self.attempt = -1

    def update(self, attempt: int, tip, inserted: bool) -> None:
        if attempt != self.attempt:  # a new attempt starts its own path
            self.points, self.attempt = [], attempt
        if not inserted:
            return
        tip = np.asarray(tip, float)
        if not self.points or np.linalg.norm(tip - self.points[-1]) >= self.STEP_MM:
            self.points.append(tip.copy())

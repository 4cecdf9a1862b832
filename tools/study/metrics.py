"""Accuracy and speed measures of the study (thesis 6.2): displacement error against a reference
field, volume change, median update time, and the largest mesh updated at a given frame rate.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TypeVar

import numpy as np


def displacement_error(u, u_ref, scale: float) -> tuple[float, float]:
    """(RMS, max) nodal error |u - u_ref| divided by the imposed displacement magnitude."""
    e = np.linalg.norm(np.asarray(u) - np.asarray(u_ref), axis=1) / scale
    return float(np.sqrt(np.mean(e**2))), float(e.max())


def volume_change(pos, tets, u) -> dict:
    """Relative change of total volume and the share of inverted tetrahedra."""

    def signed(p):
        x = p[tets]
        return np.einsum("ti,ti->t", x[:, 1] - x[:, 0], np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 0])) / 6.0

    v0 = signed(pos)
    v1 = signed(pos + u)
    s = np.sign(v0)
    rel = float((s * v1).sum() / np.abs(v0).sum() - 1.0)
    return {"volume_change": rel, "inverted_fraction": float(np.mean(s * v1 <= 0))}


T = TypeVar("T")


def median_time(fn: Callable[[], T], repeats: int = 5) -> tuple[float, T]:
    """Median wall time (s) of `fn()` over `repeats` calls, and the last result."""
    times: list[float] = []
    for _ in range(max(1, repeats)):  # at least once: `out` is always set
        t0 = time.thread_time()
        out = fn()
        times.append(time.thread_time() - t0)
    return float(np.median(times)), out


def realtime_size(n_nodes, seconds, rate_hz: float) -> float | None:
    """Largest N updated within 1/rate_hz, from a power-law fit t = a N^b of the measurements.

    Returns None when fewer than two usable points exist; the fit is extrapolated beyond the
    measured range (the report says so).
    """
    n = np.asarray(n_nodes, dtype=float)
    t = np.asarray(seconds, dtype=float)
    ok = (n > 0) & (t > 0) & np.isfinite(t)
    if ok.sum() < 2:
        return None
    b, loga = np.polyfit(np.log(n[ok]), np.log(t[ok]), 1)
    if b <= 0:
        return float("inf")
    return float(np.exp((np.log(1.0 / rate_hz) - loga) / b))


def pareto_front(points):
    """Indices of (time, error) points not dominated by any other (lower is better in both)."""
    pts = np.asarray(points, dtype=float)
    keep = []
    for i, (t, e) in enumerate(pts):
        dominated = np.any((pts[:, 0] <= t) & (pts[:, 1] <= e) & ((pts[:, 0] < t) | (pts[:, 1] < e)))
        if not dominated:
            keep.append(i)
    return sorted(keep, key=lambda i: pts[i, 0])

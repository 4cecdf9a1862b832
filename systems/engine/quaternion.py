"""Unit quaternions for needle orientation (thesis 3.3.5, eq. 3.1 and the product formula).

A quaternion is a float64 array [w, x, y, z] = (s, v). A rotation by angle theta about the unit
axis u is (cos(theta/2), u sin(theta/2)) (eq. 3.1); rotations are concatenated by the quaternion
product, `mul(q2, q1)` meaning "q1 first, then q2". Every function that produces a rotation from
products renormalises, so that millions of small incremental rotations (a dial dragged for an
hour) keep a unit norm to round-off instead of drifting.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TypeAlias

import numpy as np
from numpy.typing import ArrayLike

#: a quaternion as the functions below take it: [w, x, y, z], an array or any sequence of 4 numbers
#: (they index it, which a general ArrayLike such as a scalar does not allow)
Quat: TypeAlias = np.ndarray | Sequence[float]

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])


def mul(a: Quat, b: Quat) -> np.ndarray:
    """The Hamilton product a * b (thesis 3.3.5); as rotations: apply b, then a."""
    w1, x1, y1, z1 = float(a[0]), float(a[1]), float(a[2]), float(a[3])
    w2, x2, y2, z2 = float(b[0]), float(b[1]), float(b[2]), float(b[3])
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def conjugate(q: Quat) -> np.ndarray:
    """(s, -v): the inverse rotation for a unit quaternion."""
    return np.array([q[0], -q[1], -q[2], -q[3]], dtype=np.float64)


def norm(q: Quat) -> float:
    return math.sqrt(float(q[0]) ** 2 + float(q[1]) ** 2 + float(q[2]) ** 2 + float(q[3]) ** 2)


def normalize(q: Quat) -> np.ndarray:
    """q / |q|, with the sign fixed so that w >= 0 (q and -q are the same rotation)."""
    w, x, y, z = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (n > 1e-300) or not math.isfinite(n):
        raise ValueError(f"cannot normalise quaternion {list(q)!r}")
    if w < 0.0:
        n = -n
    w, x, y, z = w / n, x / n, y / n, z / n
    # a second pass removes the last ulp of error the division can leave
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return np.array([w / n, x / n, y / n, z / n])


def from_axis_angle(axis: ArrayLike, angle_rad: float) -> np.ndarray:
    """Eq. 3.1: rotation by `angle_rad` about `axis` (any non-zero length)."""
    u = np.asarray(axis, dtype=np.float64)
    n = float(np.linalg.norm(u))
    if not (n > 1e-300):
        raise ValueError("rotation axis must not be zero")
    u = u / n
    h = 0.5 * float(angle_rad)
    s = math.sin(h)
    return np.array([math.cos(h), u[0] * s, u[1] * s, u[2] * s])


def concat(*qs: Quat) -> np.ndarray:
    """mul(qs[-1], ... mul(qs[1], qs[0])): qs[0] applied first; renormalised."""
    out = np.asarray(qs[0], dtype=np.float64)
    for q in qs[1:]:
        out = mul(q, out)
    return normalize(out)


def rotate(q: Quat, v: ArrayLike) -> np.ndarray:
    """Rotate vector(s) v, shape (3,) or (N, 3), by the unit quaternion q (q v q*)."""
    v = np.asarray(v, dtype=np.float64)
    w = float(q[0])
    if v.shape == (3,):
        # one vector (a needle's direction, every frame): the same products in the same order on
        # Python floats, so the same bits, without numpy's per-call cost of cross
        x, y, z = float(q[1]), float(q[2]), float(q[3])
        a, b, c = float(v[0]), float(v[1]), float(v[2])
        t0, t1, t2 = 2.0 * (y * c - z * b), 2.0 * (z * a - x * c), 2.0 * (x * b - y * a)
        return np.array(
            [a + w * t0 + (y * t2 - z * t1), b + w * t1 + (z * t0 - x * t2), c + w * t2 + (x * t1 - y * t0)]
        )
    u = np.asarray(q[1:], dtype=np.float64)
    # v' = v + 2w (u x v) + 2 u x (u x v): the expanded sandwich product, fewer operations
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def to_matrix(q: Quat) -> np.ndarray:
    """3 x 3 rotation matrix (column vectors) of a unit quaternion."""
    w, x, y, z = (float(c) for c in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def from_matrix(m: ArrayLike) -> np.ndarray:
    """Unit quaternion of a 3 x 3 rotation matrix (Shepperd's method: stable for every angle)."""
    m = np.asarray(m, dtype=np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0.0:
        s = math.sqrt(tr + 1.0) * 2.0
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2.0
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2.0
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2.0
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    return normalize(q)


def look_rotation(forward: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Rotation taking local +Z to `forward` and local +Y as close to `up` as possible."""
    f = np.asarray(forward, dtype=np.float64)
    f = f / np.linalg.norm(f)
    u = np.asarray(up, dtype=np.float64)
    y = u - (u @ f) * f
    if np.linalg.norm(y) < 1e-9:  # forward parallel to up: any perpendicular will do
        y = np.array([1.0, 0.0, 0.0]) - f[0] * f
    y = y / np.linalg.norm(y)
    x = np.cross(y, f)
    return from_matrix(np.column_stack([x, y, f]))

"""Scripted motion: moves entities with a ScriptedMotion along their waypoints in simulated time.

Stage: simulation (ORDER_KINEMATICS). Reads: Time. Writes: Transform, ScriptedMotion state.
Installed only when some entity has ScriptedMotion.
"""

from __future__ import annotations

import esper
import numpy as np

from components.core import ScriptedMotion, Transform
from game.app import ORDER_KINEMATICS


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ])


def motion_system(app) -> None:
    dt = app.time.dt
    for _, (tr, mo) in esper.get_components(Transform, ScriptedMotion):
        pts = mo.waypoints.reshape(-1, 3)
        if len(pts) >= 2 and mo.speed > 0:
            step = mo.speed * dt
            while step > 0:
                a = pts[mo.segment]
                b = pts[(mo.segment + 1) % len(pts)]
                seg = float(np.linalg.norm(b - a))
                left = seg - mo.travelled
                if step < left:
                    mo.travelled += step
                    step = 0.0
                else:
                    step -= left
                    mo.travelled = 0.0
                    mo.segment += 1
                    if mo.segment >= len(pts) - (0 if mo.loop else 1):
                        if not mo.loop:
                            mo.segment = len(pts) - 2
                            mo.travelled = float(np.linalg.norm(pts[-1] - pts[-2]))
                            break
                        mo.segment = 0
            a = pts[mo.segment]
            b = pts[(mo.segment + 1) % len(pts)]
            seg = float(np.linalg.norm(b - a))
            tr.position = a + (b - a) * (mo.travelled / seg if seg > 0 else 0.0)
        if np.any(mo.spin):
            ang = np.radians(mo.spin) * dt
            for axis in range(3):
                if ang[axis]:
                    h = ang[axis] / 2
                    q = np.zeros(4)
                    q[0] = np.cos(h)
                    q[1 + axis] = np.sin(h)
                    tr.rotation = _quat_mul(q, tr.rotation)
            tr.rotation = tr.rotation / np.linalg.norm(tr.rotation)


def plugin(app) -> None:
    with app.active():
        needed = bool(esper.get_component(ScriptedMotion))
    if needed:
        app.add_system("simulation", motion_system, order=ORDER_KINEMATICS, name="motion")

"""Scripted motion: moves entities with a ScriptedMotion along their waypoints in simulated time.

Stage: simulation (ORDER_KINEMATICS). Reads: Time. Writes: Transform, ScriptedMotion state.
Installed only when some entity has ScriptedMotion.
"""

from __future__ import annotations

import esper
import numpy as np

from chainsim.components.app import App
from chainsim.components.core import ScriptedMotion, Transform
from chainsim.components.stages import ORDER_KINEMATICS
from chainsim.systems.engine import quaternion


def motion_system(app: App) -> None:
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
                    tr.rotation = quaternion.mul(quaternion.from_axis_angle(np.eye(3)[axis], ang[axis]), tr.rotation)
            tr.rotation = quaternion.normalize(tr.rotation)


def plugin(app: App) -> None:
    with app.active():
        needed = bool(esper.get_component(ScriptedMotion))
    if needed:
        app.add_system("simulation", motion_system, order=ORDER_KINEMATICS, name="motion")

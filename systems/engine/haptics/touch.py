"""The driver for 3D Systems Touch, Touch X and Phantom devices, through OpenHaptics and the pyOpenHaptics package.

Imported only when pyOpenHaptics is installed (port.DRIVERS; `--device touch` says what is missing
otherwise). OpenHaptics calls `_servo` from its own scheduler thread at 1 kHz; there the device's
position and buttons are copied out and the force last written is rendered. chainsim's servo thread
reads and writes those copies (port.DevicePort), so the two loops meet through three small buffers.
The insertion axis is the Touch's -Z: the stylus pushed away from the trainee, into the screen.
Written against pyOpenHaptics' published interface (HapticDevice, hd_callback, hd.get_transform,
hd.get_buttons, hd.set_force); not run against a device here.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pyOpenHaptics.hd as hd
from pyOpenHaptics.hd_callback import hd_callback
from pyOpenHaptics.hd_device import HapticDevice

from chainsim.systems.engine import quaternion as Q
from chainsim.systems.engine.haptics.port import DeviceSample

#: the Touch's continuous force (N); its peak is 3.3 N
TOUCH_MAX_FORCE = 0.88


class TouchPort:
    name = "touch"
    max_force_N = TOUCH_MAX_FORCE
    axis = np.array([0.0, 0.0, -1.0])
    up = np.array([0.0, 1.0, 0.0])  # the Touch's +Y

    def __init__(self, device_name: str = "Default Device"):
        self._lock = threading.Lock()
        self._position = np.zeros(3)
        self._rotation = np.eye(3)
        self._buttons = 0
        self._force = [0.0, 0.0, 0.0]
        self._t0 = time.monotonic()

        @hd_callback
        def _servo():
            t = hd.get_transform()
            buttons = hd.get_buttons()
            with self._lock:
                self._position[:] = (t[3][0], t[3][1], t[3][2])
                # OpenHaptics' transform is column-major: t[i] is the i-th column, t[3] the translation
                self._rotation[:] = [[t[c][r] for c in range(3)] for r in range(3)]
                self._buttons = int(buttons)
                force = list(self._force)
            hd.set_force(force)

        self._callback = _servo  # kept: OpenHaptics holds only a pointer to it
        self._device = HapticDevice(callback=_servo, device_name=device_name, scheduler_type="async")

    def clock(self) -> float:
        return time.monotonic() - self._t0

    def read(self) -> DeviceSample:
        with self._lock:
            position, rotation, buttons = self._position.copy(), self._rotation.copy(), self._buttons
        return DeviceSample(position, Q.from_matrix(rotation), buttons)

    def write(self, force_N: np.ndarray) -> None:
        f = np.clip(np.asarray(force_N, dtype=np.float64), -self.max_force_N, self.max_force_N)
        with self._lock:
            self._force = [float(f[0]), float(f[1]), float(f[2])]

    def close(self) -> None:
        self.write(np.zeros(3))
        self._device.close()


def open_touch(arg: str) -> TouchPort:
    """`--device touch` or `--device touch:NAME` (the OpenHaptics device name; default the default device)."""
    return TouchPort(arg or "Default Device")

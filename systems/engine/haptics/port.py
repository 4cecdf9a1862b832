"""The device port: the one interface a force-feedback device fills in, and the drivers that can fill it.

A device gives a pose and buttons and takes a force, on its own clock (`DevicePort`). The needle takes
one axis from it: the depth along the device's insertion axis (`axis`, in the device's frame) since the
needle was placed on the skin, or since the clutch button (button 0) was last let go: while the clutch
is held the hand moves without the needle, to re-centre in the device's workspace. The force goes back
along that axis.

Drivers are optional: `DRIVERS` names each with the Python package it needs, and `open_device` imports
a driver only when asked for and only when its package is installed, else says in one line what is
missing (no device library is a dependency of chainsim). The simulated device ("sim", always there) is
chainsim.systems.engine.haptics.simdevice; with a file ("sim:FILE") it plays that trajectory. Adding a
driver: a module with `open(arg) -> DevicePort`, and a line in DRIVERS (docs/haptics.md).
"""

from __future__ import annotations

import importlib
import importlib.util
import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from chainsim.systems.engine import quaternion as Q
from chainsim.systems.engine.errors import UserError


@dataclass(frozen=True, slots=True)
class DeviceSample:
    """What a device reports: position (mm, device frame), orientation (w, x, y, z), buttons (bit per button)."""

    position: np.ndarray
    orientation: np.ndarray
    buttons: int


class DevicePort(Protocol):
    """A force-feedback device. `read` and `write` are called once a servo tick, from the servo's thread."""

    name: str
    max_force_N: float
    axis: np.ndarray  # the insertion axis in the device's frame (unit)
    up: np.ndarray  # the device frame's up, the axis the needle turns about when the stylus turns left or right

    def clock(self) -> float:
        """Seconds on the device's own clock."""
        ...

    def read(self) -> DeviceSample: ...

    def write(self, force_N: np.ndarray) -> None:
        """Render this force (N, device frame) until the next write."""
        ...

    def close(self) -> None: ...


@dataclass(frozen=True, slots=True)
class Driver:
    package: str  # the Python package the driver needs
    module: str  # "module:function" returning a DevicePort
    what: str


DRIVERS: dict[str, Driver] = {
    "touch": Driver(
        "pyOpenHaptics",
        "chainsim.systems.engine.haptics.touch:open_touch",
        "3D Systems Touch, Touch X and Phantom devices through OpenHaptics",
    ),
}
SIM = "sim"


def device_names() -> list[str]:
    return [SIM, *DRIVERS]


def parse(spec: str) -> tuple[str, str]:
    """'NAME' or 'NAME:ARG' -> (name, arg); UserError for a name no driver has."""
    name, _, arg = str(spec).partition(":")
    if name != SIM and name not in DRIVERS:
        raise UserError(f"--device {spec!r}: unknown device {name!r}; known: {', '.join(device_names())}")
    return name, arg


def require(name: str) -> Driver:
    """The driver `name`, if its package is installed; else a UserError saying what to install."""
    d = DRIVERS[name]
    if importlib.util.find_spec(d.package) is None:
        raise UserError(
            f"--device {name}: needs the Python package {d.package} ({d.what}), which is not installed; "
            f"pip install {d.package}"
        )
    return d


def open_device(spec: str) -> DevicePort:
    """The driver's port for a real device named by `spec` (not "sim"); UserError naming what is missing."""
    name, arg = parse(spec)
    if name == SIM:
        raise UserError("--device sim: the simulated device runs inside the servo loop, not through a port")
    d = require(name)
    module, _, fn = d.module.partition(":")
    return getattr(importlib.import_module(module), fn)(arg)


class Depth:
    """A device's depth along its insertion axis since a reference, re-referenced by the clutch (button 0)."""

    def __init__(self, axis: np.ndarray) -> None:
        a = np.asarray(axis, dtype=np.float64)
        self.axis = a / np.linalg.norm(a)
        self.ref: np.ndarray | None = None
        self.held = 0.0  # the depth while the clutch is held
        self.clutched = False

    def __call__(self, sample: DeviceSample, placed: bool) -> float:
        p = np.asarray(sample.position, dtype=np.float64)
        if self.ref is None or not placed:
            self.ref = p.copy()  # the depth counts from where the hand is when the needle is placed
            return 0.0
        if sample.buttons & 1:
            if not self.clutched:
                self.clutched, self.held = True, float((p - self.ref) @ self.axis)
            return self.held
        if self.clutched:  # let go: the depth goes on from where it was held
            self.clutched = False
            self.ref = p - self.held * self.axis
        return float((p - self.ref) @ self.axis)


#: how stiffly tissue holds an inserted needle on its line, per mm of needle in it (N/mm per mm): a shaft in
#: tissue is a beam on an elastic bed, its lateral resistance growing with the length embedded
LATERAL_K_PER_MM = 0.02
#: at most the coupling's own stiffness (model.new_cfg: 0.6 N/mm), reached with 30 mm in tissue
LATERAL_K_MAX = 0.6


class Lateral:
    """The force holding the hand on the needle's line once the needle is in tissue: a spring-damper on the
    hand's offset across the insertion axis from where it was when the skin gave, stiffer the deeper the
    needle is (zero at the skin, so the force starts without a step).

    A needle in tissue cannot move sideways; the device renders that as a force back to the line (a 3-DOF
    device renders no torque, so a stylus turned in tissue is not resisted). Out of tissue: no force. The
    damper on the backward difference keeps it passive as the axial wall is (b >= k T / 2 at the largest k,
    docs/haptics.md): b is the coupling's damping, 0.0006 N s/mm against 0.6 * 0.001 / 2."""

    def __init__(self, axis: np.ndarray, dt: float, damping: float) -> None:
        self.axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
        self.dt, self.b = float(dt), float(damping)
        self.last: np.ndarray | None = None
        self.entry: np.ndarray | None = None  # the hand's offset across the axis when the needle went in

    def __call__(self, position: np.ndarray, ref: np.ndarray | None, embedded_mm: float) -> np.ndarray:
        """The force on the hand (N, device frame) with the needle `embedded_mm` in tissue."""
        if ref is None or embedded_mm <= 0.0:
            self.last = self.entry = None
            return np.zeros(3)
        d = np.asarray(position, dtype=np.float64) - ref
        off = d - (d @ self.axis) * self.axis
        if self.entry is None:  # the line is where the hand was when the needle went in
            self.entry = off
        off = off - self.entry
        v = np.zeros(3) if self.last is None else (off - self.last) / self.dt
        self.last = off
        k = min(LATERAL_K_PER_MM * embedded_mm, LATERAL_K_MAX)
        return -(k * off + self.b * v)


#: a turn of the stylus smaller than this (degrees) leaves the dials where they are (a hand's tremor)
AIM_DEADBAND_DEG = 0.25


class Aim:
    """The needle's heading from the stylus's orientation, while the needle may turn (outside tissue).

    `start(orientation)` takes the stylus's orientation as the needle's heading now; `turned(orientation)`
    gives the (left-right, up-down) turn since then in degrees, as the needle's dials count them: the
    insertion axis turned by the stylus's rotation, its heading about the device's `up` (counter-clockwise
    seen from above, positive) and its tilt towards `up` (raising the tip, positive)."""

    def __init__(self, axis: np.ndarray, up: np.ndarray) -> None:
        a = np.asarray(axis, dtype=np.float64)
        self.axis = a / np.linalg.norm(a)
        side = np.cross(np.asarray(up, dtype=np.float64), self.axis)
        self.side = side / np.linalg.norm(side)
        self.up = np.cross(self.axis, self.side)
        self.ref: np.ndarray | None = None  # the stylus's orientation at start, as a matrix

    def start(self, orientation: np.ndarray) -> None:
        self.ref = Q.to_matrix(Q.normalize(orientation))

    def turned(self, orientation: np.ndarray) -> tuple[float, float]:
        if self.ref is None:
            return 0.0, 0.0
        d = Q.to_matrix(Q.normalize(orientation)) @ self.ref.T @ self.axis
        a, s, u = float(d @ self.axis), float(d @ self.side), float(d @ self.up)
        return math.degrees(math.atan2(s, a)), math.degrees(math.atan2(u, math.hypot(a, s)))

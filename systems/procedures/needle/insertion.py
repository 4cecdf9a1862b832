"""A straight insertion along a needle pack's textbook path, as timed input events (benchmarks, studies).

The pack's anatomy names its paths (`[paths]`: entry on the skin, target); this places the needle at
the first path's entry (a pick for every landmark the pack asks for, all at the entry), turns the
dials so the needle points at the target (the kinematics' conventions: a horizontal turn from the
level start toward `aim_at`, then the tilt) and asks for the path's depth less 2 mm, which the needle
reaches at the pack's insert_speed.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from chainsim.components.input_events import PickPoint, Widget


def straight_insertion(root: Path, manifest: dict) -> tuple[list, float, float]:
    """Events placing the needle at the first path's entry and aiming it at the target, then the depth the
    needle advances to and the time it gets there."""
    anatomy = tomllib.loads((root / "anatomy.toml").read_text())
    path = next(iter(anatomy["paths"].values()))
    entry, target = np.array(path["entry"], float), np.array(path["target"], float)
    d = (target - entry) / np.linalg.norm(target - entry)
    needle = manifest["entities"]["needle"]["needle"]
    aim = np.array(needle.get("aim_at", [0.0, 0.0, 0.0]), float)
    start = np.array([aim[0] - entry[0], aim[1] - entry[1], 0.0])
    start /= np.linalg.norm(start)
    flat = np.array([d[0], d[1], 0.0]) / np.linalg.norm(d[:2])
    yaw = float(np.degrees(np.arctan2(start[0] * flat[1] - start[1] * flat[0], start @ flat)))
    pitch = float(np.degrees(np.arcsin(d[2])))
    depth = float(np.linalg.norm(target - entry)) - 2.0
    n_landmarks = max(1, len(manifest.get("landmarks", [])))
    point = (float(entry[0]), float(entry[1]), float(entry[2]))
    ev: list[tuple[float, PickPoint | Widget]] = [(0.2 + 0.1 * i, PickPoint("skin", point)) for i in range(n_landmarks)]
    ev += [
        (1.0, Widget("rotate_horizontal", yaw)),
        (1.2, Widget("rotate_vertical", pitch)),
        (1.5, Widget("insert", depth)),
    ]
    return ev, depth, 1.5 + depth / float(needle.get("insert_speed") or 1e9)

"""A straight needle insertion along a needle pack's textbook path, as an input script (tests' helper)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
ASSETS = ROOT / "assets"
#: path name in anatomy.toml, mesh of that side, depth to insert to (mm)
CASES = {"prp": ("left", "tissue_left.vtu", 40.0), "mental-block": ("mental_left", "tissue_left.vtu", 14.0)}


def manifest(pack: str) -> dict:
    return tomllib.loads((ASSETS / pack / "pack.toml").read_text())


def anatomy(pack: str) -> dict:
    return tomllib.loads((ASSETS / pack / "anatomy.toml").read_text())


def insertion_script(pack: str, path: str, depth: float, then: list[tuple[float, float]] = ()) -> str:
    """Pick the path's entry three times over (landmarks), aim along the path, insert to `depth` (the needle
    advances at the pack's insert_speed), then the (time, depth) pairs of `then`."""
    an = anatomy(pack)
    p = an["paths"][path]
    entry, target = np.array(p["entry"]), np.array(p["target"])
    d = (target - entry) / np.linalg.norm(target - entry)
    # the dials: horizontal turn from the level start direction, then the tilt (kinematics' conventions)
    needle = manifest(pack)["entities"]["needle"]["needle"]
    aim = np.array(needle.get("aim_at", [0.0, 0.0, 0.0]))
    start = np.array([aim[0] - entry[0], aim[1] - entry[1], 0.0])
    start /= np.linalg.norm(start)
    flat = np.array([d[0], d[1], 0.0]) / np.linalg.norm(d[:2])
    yaw = np.degrees(np.arctan2(start[0] * flat[1] - start[1] * flat[0], start @ flat))
    pitch = np.degrees(np.arcsin(d[2]))
    picks = [pt["position"] for name, pt in an["points"].items() if name.startswith("landmark") and "left" in name]
    if not picks:  # mental-block names its landmarks otherwise: the entry three times is enough to place
        picks = [list(entry)] * 3
    picks = [list(entry)] + picks[1:3] if len(picks) >= 3 else [list(entry)] * 3
    ev = []
    for i, pt in enumerate(picks):
        ev.append(f'[[event]]\nt = {0.5 + 0.5 * i}\nkind = "pick"\nentity = "skin"\npoint = {list(map(float, pt))}\n')
    ev.append(f'[[event]]\nt = 2.0\nkind = "widget"\nname = "rotate_horizontal"\nvalue = {yaw}\n')
    ev.append(f'[[event]]\nt = 2.5\nkind = "widget"\nname = "rotate_vertical"\nvalue = {pitch}\n')
    ev.append(f'[[event]]\nt = 3.0\nkind = "widget"\nname = "insert"\nvalue = {depth}\n')
    for t, dd in then:
        ev.append(f'[[event]]\nt = {t}\nkind = "widget"\nname = "insert"\nvalue = {dd}\n')
    return "format = 1\n\n" + "\n".join(ev)

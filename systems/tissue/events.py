"""Requests to deformable bodies and what they report back (events on `app.events`).

Anything that wants to deform tissue (a tool system, the mouse, a scripted puller, a test) emits one
of the requests below; `chainsim.systems.tissue.deformation` serves them in the simulation stage and answers with
`Deformed`. Entities may be named by id or by manifest name.

Coordinates: `frame="world"` (the default) means millimetres in the scene frame, as `Picked` events
deliver them; the system maps them into the body's local frame through its Transform. `frame="local"`
means the mesh's own frame (the frame of the soft body's `rest` and `positions`, `Deformable.body`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

FRAMES = ("world", "local")


@dataclass(frozen=True, slots=True)
class GrabRequest:
    """Move elements `ids` to `targets` (K, 3) and let the ChainMail cascade carry the rest (5.2.3).

    With `hold`, the ids stay pinned for relaxation until a ReleaseRequest (a tool keeps gripping).
    """

    entity: Any
    ids: Any
    targets: Any
    frame: str = "world"
    hold: bool = True


@dataclass(frozen=True, slots=True)
class ReleaseRequest:
    """Let go of the held elements (all of them, or only `ids`)."""

    entity: Any
    ids: Any = None


@dataclass(frozen=True, slots=True)
class ResetRequest:
    """Put the body back at rest: rest positions, every link restored, nothing held."""

    entity: Any


@dataclass(frozen=True, slots=True)
class CutRequest:
    """Cut links crossed by a blade (thesis 4.5.2).

    A segment `p0`-`p1` swept along `normal` (the blade's depth direction; None: the plane through the
    segment and the body's local z axis), or a `polyline` (L, 3) cut piece by piece.
    """

    entity: Any
    p0: Any = None
    p1: Any = None
    normal: Any = None
    polyline: Any = None
    depth: float = 1e9
    frame: str = "world"


@dataclass(frozen=True, slots=True)
class AddLinksRequest:
    """Join elements with new links (suturing, stapling); rest length is their current distance."""

    entity: Any
    links: Any


@dataclass(frozen=True, slots=True)
class Deformed:
    """A body changed this step: `moved_count` elements moved, `cut_count` links were cut."""

    entity: int
    moved_count: int
    cut_count: int = 0
    added_count: int = 0


def as_points(value, where: str) -> np.ndarray:
    """(K, 3) float64 from a point or list of points; ValueError naming `where` otherwise."""
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr.reshape(1, -1)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{where}: expected points of 3 coordinates, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{where}: coordinates must be finite")
    return arr

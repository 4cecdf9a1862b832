"""Meshes read once: what `chainsim.systems.engine.meshes.load_file` made of a file, kept on disk.

Parsing a pack's surface and volume files needs trimesh and meshio, whose imports alone take most of
a second on a 2-core machine; a later start of the same pack reads the arrays it got last time
instead (numpy's own format) and imports neither. An entry is found by a hash of the file's bytes,
its type and the loading options, so an edited file is parsed again; entries are only ever written
whole (chainsim.systems.engine.atomicfile). The folder is $CHAINSIM_CACHE_DIR, else chainsim/meshes in
the user's cache folder ($XDG_CACHE_HOME or ~/.cache). A folder that cannot be written only means
parsing every time. What comes back is checked like a parsed mesh (chainsim.systems.engine.meshes).
"""

from __future__ import annotations

import functools
import hashlib
import os
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from chainsim.systems.engine.atomicfile import atomic_open

#: raised when what a load makes of a file changes: older entries are then never read
VERSION = 1
FIELDS = ("vertices", "triangles", "tets", "links", "fixed", "layers")


def folder() -> Path:
    """Where entries live (see the module docstring)."""
    own = os.environ.get("CHAINSIM_CACHE_DIR")
    if own:
        return Path(own) / "meshes"
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "chainsim" / "meshes"


def key(data: bytes, ext: str, scale: float, merge_vertices: bool) -> str:
    """The entry's name for a file's bytes read with these options (and the parsers' versions: another
    trimesh or meshio may read the same file otherwise)."""
    h = hashlib.sha256(data)
    h.update(f"|{ext}|{scale!r}|{merge_vertices}|{VERSION}|{_parsers()}".encode())
    return h.hexdigest()


@functools.cache
def _parsers() -> str:
    out = []
    for dist in ("trimesh", "meshio"):
        try:
            out.append(f"{dist} {metadata.version(dist)}")
        except metadata.PackageNotFoundError:
            out.append(f"{dist} ?")
    return ", ".join(out)


def read(name: str) -> dict[str, np.ndarray | None] | None:
    """The arrays of entry `name` (None where the mesh had none), or None when there is no usable entry."""
    path = folder() / f"{name}.npz"
    try:
        with np.load(path, allow_pickle=False) as z:
            return {f: (z[f] if f in z.files else None) for f in FIELDS}
    except (OSError, ValueError, KeyError):  # none yet, or cut short by another process: parse instead
        return None


def write(name: str, arrays: dict[str, np.ndarray | None]) -> None:
    """Keep `arrays` as entry `name`; a folder that cannot be written is left alone."""
    try:
        folder().mkdir(parents=True, exist_ok=True)
        with atomic_open(folder() / f"{name}.npz", "wb") as fh:
            kept: dict[str, Any] = {k: v for k, v in arrays.items() if v is not None}
            np.savez(fh, **kept)
    except OSError:
        pass  # a cache only: the next start parses the file again

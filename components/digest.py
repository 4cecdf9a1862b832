"""A digest of world state: equal digests mean bit-identical components and simulated time.

Entities are visited in id order and components in type-name order; numpy arrays contribute
dtype, shape and raw bytes, floats their IEEE-754 bits. A component's fields marked `digest: False` are
left out; one that keeps state on an object it holds names it, as (name, value) pairs fed after its
fields, with a `digest_items()` method. Used to check determinism and replays.
"""

from __future__ import annotations

import dataclasses
import hashlib
import struct

import esper
import numpy as np

from chainsim.components.app import App


def _feed(h, value) -> None:
    if isinstance(value, np.ndarray):
        h.update(b"A" + str(value.dtype).encode() + str(value.shape).encode())
        h.update(np.ascontiguousarray(value).tobytes())
    elif isinstance(value, bool):
        h.update(b"B1" if value else b"B0")
    elif isinstance(value, int):
        h.update(b"I" + str(value).encode())
    elif isinstance(value, float):
        h.update(b"F" + struct.pack("<d", value))
    elif isinstance(value, str):
        h.update(b"S" + value.encode() + b"\0")
    elif isinstance(value, (list, tuple)):
        h.update(b"L" + str(len(value)).encode())
        for v in value:
            _feed(h, v)
    elif isinstance(value, (set, frozenset)):
        _feed(h, sorted(value, key=repr))
    elif isinstance(value, dict):
        h.update(b"D" + str(len(value)).encode())
        for k in sorted(value, key=repr):
            _feed(h, k)
            _feed(h, value[k])
    elif dataclasses.is_dataclass(value):
        h.update(b"C" + type(value).__name__.encode())
        for f in dataclasses.fields(value):
            if f.metadata.get("digest", True):
                h.update(f.name.encode())
                _feed(h, getattr(value, f.name))
        # state a component keeps on an object it holds (a soft body), fed as if they were its fields
        for name, item in value.digest_items() if hasattr(value, "digest_items") else ():
            h.update(name.encode())
            _feed(h, item)
    elif value is None:
        h.update(b"N")
    else:
        h.update(b"R" + repr(value).encode())


def world_digest(app: App) -> str:
    """SHA-256 over every entity's components and the simulation tick."""
    h = hashlib.sha256()
    _feed(h, app.time.tick)
    with app.active():
        for ent in sorted(esper._entities):
            h.update(b"E" + str(ent).encode())
            comps = esper.components_for_entity(ent)
            for c in sorted(comps, key=lambda c: type(c).__name__):
                _feed(h, c)
    return h.hexdigest()

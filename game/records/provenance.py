"""What an uploaded attempt carries so the records server can compute its result itself.

An upload holds, beside the simulator's own figures, the attempt's input recording (the JSON that
``--record`` writes, from the session's start to the Save) and the identity of the pack it ran
on: name, version and a SHA-256 over the pack's files (and those of the packs it requires). The
server replays the recording on its copy of that pack (``chainsim.game.server.scoring``) and keeps
the replay's figures; the identity is how it knows the copy is the same.

Recordings travel and are kept compressed (zlib, then base64 so that both databases store them as
text), at most ``MAX_RECORDING_BYTES`` compressed and ``MAX_RECORDING_INFLATED`` once inflated
(docs/limits.md): a small upload cannot inflate into a large one.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import json
import os
import zlib
from pathlib import Path
from typing import Any

from chainsim.systems.engine import limits
from chainsim.systems.engine.errors import UserError

#: compressed size of one attempt's recording, and the same recording as JSON (docs/limits.md)
MAX_RECORDING_BYTES = limits.MAX_RECORDING_BYTES
MAX_RECORDING_INFLATED = limits.MAX_RECORDING_INFLATED
_SKIP_DIRS = {"__pycache__", ".git"}
_hash_cache: dict[tuple, str] = {}


def _files(root: Path) -> list[Path]:
    out = []
    for folder, dirs, names in os.walk(root):
        dirs[:] = sorted(d for d in dirs if d not in _SKIP_DIRS and not d.startswith("."))
        out += [Path(folder) / n for n in sorted(names) if not n.startswith(".") and not n.endswith(".pyc")]
    return out


def files_listing(roots: list[Path]) -> tuple:
    """``(root index, relative name, size, mtime_ns)`` of every file of ``roots``, in a fixed order.

    A pack whose listing is unchanged has unchanged files (an editor or a copy that replaces a file
    changes its size or its time); a file that vanishes mid-walk counts as a change."""
    listing = []
    for i, root in enumerate(roots):
        for path in _files(root):
            try:
                st = path.stat()
            except OSError:
                st = None
            listing.append((i, path.relative_to(root).as_posix(), st and st.st_size, st and st.st_mtime_ns))
    return tuple(listing) + tuple(str(r) for r in roots)


def files_hash(roots: list[Path]) -> str:
    """SHA-256 over every file of ``roots`` (relative names and contents), in a fixed order."""
    # hashing is keyed on names, sizes and times: a save does not reread an unchanged pack
    key = files_listing(roots)
    cached = _hash_cache.get(key)
    if cached is not None:
        return cached
    h = hashlib.sha256()
    for i, rel, _, _ in key[: len(key) - len(roots)]:
        h.update(f"{i}\0{rel}\0".encode())
        h.update(hashlib.sha256((roots[i] / rel).read_bytes()).digest())
    _hash_cache[key] = digest = h.hexdigest()
    return digest


def pack_identity(pack: Any) -> dict[str, str]:
    """``{"name", "version", "hash"}`` of a loaded pack (``chainsim.game.packs.model.Pack``)."""
    roots = [Path(pack.root)] + [Path(p) for _, p in sorted(pack.deps.items())]
    return {
        "name": pack.name,
        "version": str(pack.manifest["pack"].get("version", "")),
        "hash": files_hash(roots),
    }


def clean_identity(value: Any) -> dict[str, str]:
    """An upload's ``pack_identity``, checked: name, version and a 64-digit hex hash."""
    if not isinstance(value, dict) or set(value) != {"name", "version", "hash"}:
        raise UserError("pack_identity must be an object with name, version and hash (the pack the attempt ran on)")
    for key in ("name", "version", "hash"):
        if not isinstance(value[key], str) or len(value[key]) > 200:
            raise UserError(f"pack_identity.{key} must be text of at most 200 characters")
    h = value["hash"]
    if len(h) != 64 or any(c not in "0123456789abcdef" for c in h):
        raise UserError("pack_identity.hash must be 64 lowercase hex digits (SHA-256 of the pack's files)")
    return dict(value)


def encode_recording(recording: dict) -> str:
    """The recording as compact JSON, zlib-compressed, base64 text."""
    raw = json.dumps(recording, separators=(",", ":"), allow_nan=False).encode()
    return base64.b64encode(zlib.compress(raw, 9)).decode("ascii")


def check_recording_text(text: Any) -> None:
    """UserError unless ``text`` looks like ``encode_recording`` output within the compressed size limit;
    reads nothing of what it holds (that is the scorer's work)."""
    if not isinstance(text, str) or not text:
        raise UserError("recording must be the compressed text the simulator sends (base64 of zlib JSON)")
    if len(text) > MAX_RECORDING_BYTES * 4 // 3 + 4:
        raise UserError(f"recording is over {MAX_RECORDING_BYTES} bytes compressed (docs/limits.md)")


def decode_recording(text: Any) -> dict:
    """A recording from ``encode_recording`` text, within the size limits; UserError naming what is wrong."""
    check_recording_text(text)
    try:
        packed = base64.b64decode(text, validate=True)
        inflater = zlib.decompressobj()
        raw = inflater.decompress(packed, MAX_RECORDING_INFLATED + 1)
    except (binascii.Error, ValueError, zlib.error):
        raise UserError("recording is not base64 of zlib-compressed JSON") from None
    if len(raw) > MAX_RECORDING_INFLATED or inflater.unconsumed_tail:
        raise UserError(f"recording inflates past {MAX_RECORDING_INFLATED} bytes (docs/limits.md)")
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        raise UserError("recording is not valid JSON once inflated") from None
    if not isinstance(data, dict) or data.get("chainsim") != "recording":
        raise UserError("recording is not a chainsim recording (expected the JSON that --record writes)")
    return data

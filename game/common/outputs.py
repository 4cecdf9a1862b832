"""Output paths a user names (`--out`, `--record`, `--csv`, ...): checked before work starts, written atomically.

A long run must not end in a traceback because its output path names a folder, a missing folder or
a read-only one. `check_output_file` and `prepare_output_dir` are called before anything runs and
say, in one line naming the flag, what is wrong; `write_text_atomic`/`write_bytes_atomic` write through
`chainsim.systems.engine.atomicfile` (a temporary file in the same folder renamed into place), so an
interrupted or failed write never leaves half a file where a good one was. Permission checks use
os.access, which reports what the running user may do (root ignores permissions, so tests run them as
an unprivileged user).
"""

from __future__ import annotations

import os
from pathlib import Path

from chainsim.systems.engine import atomicfile
from chainsim.systems.engine.errors import UserError


def _usable(path: str | os.PathLike, flag: str) -> Path:
    text = os.fspath(path)
    if not text:
        raise UserError(f"{flag}: empty path")
    if "\x00" in text:
        raise UserError(f"{flag} {text!r}: a path cannot contain a NUL byte")
    return Path(text)


def check_output_file(path: str | os.PathLike, flag: str) -> Path:
    """A file we may create or replace: not a folder, its folder exists and is writable."""
    p = _usable(path, flag)
    if p.is_dir():
        raise UserError(f"{flag} {p}: is a folder; expected a file name")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.exists():
        raise UserError(f"{flag} {p}: folder {parent} does not exist")
    if not parent.is_dir():
        raise UserError(f"{flag} {p}: {parent} is not a folder")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UserError(f"{flag} {p}: folder {parent} is not writable")
    if p.exists() and not os.access(p, os.W_OK):
        raise UserError(f"{flag} {p}: the file is read-only")
    return p


def prepare_output_dir(path: str | os.PathLike, flag: str) -> Path:
    """A folder we may write into, created (with its parents) when missing."""
    p = _usable(path, flag)
    if p.exists() and not p.is_dir():
        raise UserError(f"{flag} {p}: is a file; expected a folder")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"{flag} {p}: cannot create folder ({e.strerror or e})") from None
    if not os.access(p, os.W_OK | os.X_OK):
        raise UserError(f"{flag} {p}: folder is not writable")
    return p


def write_bytes_atomic(path: str | os.PathLike, data: bytes, flag: str) -> None:
    """Write `data` to a temporary file beside `path`, then rename it into place; one line on failure."""
    p = check_output_file(path, flag)
    try:
        atomicfile.write_bytes(p, data)
    except OSError as e:
        raise UserError(f"{flag} {p}: cannot write ({e.strerror or e})") from None


def write_text_atomic(path: str | os.PathLike, text: str, flag: str) -> None:
    write_bytes_atomic(path, text.encode("utf-8"), flag)

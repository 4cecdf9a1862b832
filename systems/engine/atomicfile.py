"""Writing a file so that it is either the old one or the whole new one, never half of either.

Outputs a user keeps and may overwrite (recordings, run summaries, records exports and plots,
screenshots, chainmail results, material presets, benchmark results, the remembered sign-in) are
written through `atomic_open`: into a temporary file beside the target (same folder, so the rename
cannot cross file systems), flushed and fsynced, then renamed over the target with os.replace. A
failure or an interrupt while writing removes the temporary file and leaves whatever was at the
target untouched. The engine is the bottom layer, so every layer above can use this.
"""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any


@contextlib.contextmanager
def atomic_open(
    path: str | os.PathLike, mode: str = "w", *, encoding: str = "utf-8", newline: str | None = None
) -> Iterator[IO]:
    """A file open for writing ("w" text or "wb" bytes) whose content replaces `path` when the block ends
    without an exception. OSError from creating, writing or renaming reaches the caller, which says
    what could not be written in its own words."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open writes whole files: mode 'w' or 'wb', not {mode!r}")
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        kwargs: dict[str, Any] = {} if mode == "wb" else {"encoding": encoding, "newline": newline}
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        # mkstemp makes the file owner-only; the result gets the mode a plain open() would give it
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_open(path, "wb") as fh:
        fh.write(data)


def write_text(path: str | os.PathLike, text: str, *, encoding: str = "utf-8") -> None:
    with atomic_open(path, "w", encoding=encoding) as fh:
        fh.write(text)


def _umask() -> int:
    # /proc says it without changing it (setting and restoring it races with other threads' files)
    try:
        m = re.search(r"^Umask:\s*([0-7]+)", Path("/proc/self/status").read_text(), re.M)
        if m:
            return int(m.group(1), 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask

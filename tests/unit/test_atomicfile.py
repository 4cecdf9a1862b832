"""The one atomic file writer: the target is the old file or the whole new one, and no temporary file
is left beside it, whatever goes wrong while writing."""

import os
import stat

import numpy as np
import pytest

from chainsim.systems.engine import atomicfile
from chainsim.systems.engine.errors import UserError


def test_a_write_replaces_the_file_with_the_usual_mode(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("old", encoding="utf-8")
    atomicfile.write_text(path, "new\n")
    assert path.read_text(encoding="utf-8") == "new\n"
    atomicfile.write_bytes(tmp_path / "b.bin", b"\x00\x01")
    assert (tmp_path / "b.bin").read_bytes() == b"\x00\x01"
    umask = os.umask(0o022)
    os.umask(umask)
    # not mkstemp's owner-only 0600: what open() would have made
    assert stat.S_IMODE((tmp_path / "b.bin").stat().st_mode) == 0o666 & ~umask
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b.bin", "out.txt"]


def test_an_error_while_writing_leaves_the_old_file_and_no_temporary_file(tmp_path):
    path = tmp_path / "results.json"
    path.write_text('{"good": 1}', encoding="utf-8")
    with pytest.raises(RuntimeError, match="half way"):
        with atomicfile.atomic_open(path, "w") as fh:
            fh.write('{"partial": ')
            raise RuntimeError("half way")
    assert path.read_text(encoding="utf-8") == '{"good": 1}'
    assert [p.name for p in tmp_path.iterdir()] == ["results.json"]


def test_an_interrupt_or_a_failed_sync_leaves_the_old_file(tmp_path, monkeypatch):
    path = tmp_path / "shot.png"
    path.write_bytes(b"old picture")
    with pytest.raises(KeyboardInterrupt):
        with atomicfile.atomic_open(path, "wb") as fh:
            fh.write(b"new")
            raise KeyboardInterrupt

    def full_disk(fd):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(OSError, match="No space"):
        atomicfile.write_bytes(path, b"new picture")
    assert path.read_bytes() == b"old picture"
    assert [p.name for p in tmp_path.iterdir()] == ["shot.png"]


def test_the_callers_say_what_could_not_be_written_and_keep_the_old_file(tmp_path, monkeypatch):
    from chainsim.game.cli.commands.chainmail import write_result
    from chainsim.game.common.outputs import write_text_atomic

    out = tmp_path / "result.npz"
    out.write_bytes(b"previous result")

    def savez_then_full_disk(fh, **arrays):
        fh.write(b"PK\x03\x04 half an archive")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez", savez_then_full_disk)
    with pytest.raises(UserError, match=r"--out: cannot write .*result\.npz \(No space left on device\)"):
        write_result(out, np.zeros((2, 3)), np.arange(2), np.arange(2))
    assert out.read_bytes() == b"previous result"
    monkeypatch.setattr(os, "replace", lambda a, b: (_ for _ in ()).throw(OSError(13, "Permission denied")))
    with pytest.raises(UserError, match=r"--record .*cannot write \(Permission denied\)"):
        write_text_atomic(tmp_path / "rec.json", "{}", "--record")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["result.npz"]

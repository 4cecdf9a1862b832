"""The browser trainer's pictures as tiles: only the parts of the window that changed are encoded and sent.

A trainee turning a dial changes the controller's dial, the needle in two or three views and a line of
text; the other views stand still (the renderer keeps their images, ``Renderer.cache_views``). So the
session process (``chainsim.game.server.train_session``) compares each picture with the last one it
sent, cuts the difference into runs of changed TILE-pixel tiles along each row of tiles, and sends
those runs only, each its own small JPEG (or WebP). The page (``static/train.js``) draws each run at its
place over the picture it has. Encoding a fifth of the window costs about a fifth of encoding all of
it, and the link carries a fifth of the bytes.

Wire format of one frame's payload (all big-endian): frame number (uint32), the last input sequence
number the picture shows (uint32), the number of runs (uint16), then per run x, y, width, height
(uint16 each, pixels from the top-left) and the encoded bytes' length (uint32) followed by the bytes.
"""

from __future__ import annotations

import io
import struct

import numpy as np

#: side of a tile in pixels: a multiple of 16, so JPEG's 8x8 blocks and 2x2 chroma never straddle tiles
TILE = 64
#: past this share of the picture changed, one run of the whole picture (one header, better compression)
WHOLE_SHARE = 0.6
HEAD = struct.Struct(">IIH")
RUN = struct.Struct(">HHHHI")


def changed_runs(prev: np.ndarray | None, cur: np.ndarray, tile: int = TILE) -> list[tuple[int, int, int, int]]:
    """(x, y, w, h) of the parts of `cur` (H, W, 3, rows top first) that differ from `prev`: runs of
    changed tiles along each row of tiles, the whole picture when `prev` is None, of another size or
    mostly changed, and none when nothing changed."""
    h, w = cur.shape[:2]
    if prev is None or prev.shape != cur.shape:
        return [(0, 0, w, h)]
    ny, nx = -(-h // tile), -(-w // tile)
    if (w * 3) % 8 == 0 and (tile * 3) % 8 == 0:
        # eight bytes at a time: a tile's row is tile * 3 / 8 words, so words never straddle tiles
        a = np.ascontiguousarray(prev).reshape(h, w * 3).view(np.uint64)
        b = np.ascontiguousarray(cur).reshape(h, w * 3).view(np.uint64)
        per = tile * 3 // 8
        diff = np.zeros((ny * tile, nx * per), bool)
        diff[:h, : a.shape[1]] = a != b
        blocks = np.any(diff.reshape(ny, tile, nx, per), axis=(1, 3))
    else:
        diff = np.zeros((ny * tile, nx * tile), bool)
        diff[:h, :w] = np.any(prev != cur, axis=2)
        blocks = np.any(diff.reshape(ny, tile, nx, tile), axis=(1, 3))
    if blocks.sum() > WHOLE_SHARE * blocks.size:
        return [(0, 0, w, h)]
    runs = []
    for j in range(ny):
        i = 0
        while i < nx:
            if not blocks[j, i]:
                i += 1
                continue
            start = i
            while i < nx and blocks[j, i]:
                i += 1
            x, y = start * tile, j * tile
            runs.append((x, y, min(i * tile, w) - x, min(tile, h - y)))
    return runs


def encode_rgb(rgb: np.ndarray, fmt: str, quality: int) -> bytes:
    """One (h, w, 3) uint8 picture, rows top first, as JPEG or WebP bytes."""
    from PIL import Image  # noqa: PLC0415 - the session process only

    out = io.BytesIO()
    im = Image.fromarray(np.ascontiguousarray(rgb), "RGB")
    if fmt == "webp":
        im.save(out, "WEBP", quality=quality, method=0)
    else:
        im.save(out, "JPEG", quality=quality)
    return out.getvalue()


def pack_frame(number: int, seq: int, cur: np.ndarray, runs, fmt: str, quality: int) -> bytes:
    """The payload of one frame: its header and each run of `cur` encoded (module docstring)."""
    parts = [HEAD.pack(number & 0xFFFFFFFF, seq & 0xFFFFFFFF, len(runs))]
    for x, y, w, h in runs:
        data = encode_rgb(cur[y : y + h, x : x + w], fmt, quality)
        parts.append(RUN.pack(x, y, w, h, len(data)))
        parts.append(data)
    return b"".join(parts)


def unpack_frame(payload: bytes) -> tuple[int, int, list[tuple[int, int, int, int, bytes]]]:
    """(frame number, input seq, [(x, y, w, h, encoded bytes)]) of a payload: what the page reads."""
    number, seq, n = HEAD.unpack_from(payload, 0)
    at, runs = HEAD.size, []
    for _ in range(n):
        x, y, w, h, size = RUN.unpack_from(payload, at)
        at += RUN.size
        runs.append((x, y, w, h, payload[at : at + size]))
        at += size
    return number, seq, runs

"""PNG output of framebuffer pixels (pillow)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from chainsim.systems.engine.atomicfile import atomic_open
from chainsim.systems.engine.errors import UserError


def read_rgba(fbo, viewport=None) -> np.ndarray:
    """The framebuffer's pixels as (H, W, 4) uint8, top row first (image order)."""
    w, h = viewport[2:] if viewport else fbo.size
    raw = fbo.read(viewport=viewport, components=4, alignment=1)
    return np.frombuffer(raw, np.uint8).reshape(h, w, 4)[::-1].copy()


def write_png(path, rgba: np.ndarray) -> Path:
    """Write (H, W, 4) uint8 pixels atomically (a partial file never replaces a good one)."""

    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_open(path, "wb") as fh:
            Image.fromarray(rgba[:, :, :3] if rgba.shape[2] == 4 else rgba, "RGB").save(fh, format="PNG")
    except OSError as e:
        raise UserError(f"{path}: cannot write the PNG ({e.strerror or e})") from None
    return path

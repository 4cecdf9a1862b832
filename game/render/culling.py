"""Leaving out, before the GPU sees them, the triangles of a big mesh that cannot show in a draw.

Under a software renderer (llvmpipe) every triangle handed to a draw costs its vertex shading,
clipping and set-up even when none of its pixels is inside the viewport or the scissor box: the
needle-tip view looks at a small part of the skull from close by, and the pass that blends the
see-through skin again around a moving needle covers a small box of the surgeon's view, yet both
handed over every triangle. `visible_triangles` finds, on the CPU, the triangles wholly outside one
side of the drawn region - the scissor box (within the viewport) between the near and far planes -
which produce no fragment, and the renderer draws the rest in the same order as before (the
nearest-first order of an opaque mesh, the stored order of a blended one), so each pixel gets the
same fragments in the same order and the image is the same.

The test is exact and conservative: in clip coordinates the drawn region is the intersection of six
half-spaces (x >= x0 w, x <= x1 w, the same in y, -w <= z <= w), so a triangle whose three corners
lie outside one of them lies outside wholly; the region is widened by a pixel on each side against
rounding. Pure numpy on arrays; no GL.
"""

from __future__ import annotations

import numpy as np

#: meshes with fewer triangles are drawn whole (the test would cost more than it saves)
CULL_MIN = 4000
#: culling pays only when it leaves out at least this share of the triangles (else drawn whole)
CULL_SHARE = 0.25


def region_planes(mvp: np.ndarray, viewport, scissor=None, margin: float = 1.0) -> np.ndarray | None:
    """The six half-spaces (rows a, b, c, d: inside where a x + b y + c z + d >= 0, x y z in the
    mesh's frame) bounding what a draw with model-view-projection `mvp` can touch in the pixels of
    `viewport` (x, y, w, h) within `scissor` (or the whole viewport), widened by `margin` pixels;
    None when that rectangle is empty."""
    vx, vy, vw, vh = (float(v) for v in viewport)
    x0, y0, x1, y1 = vx, vy, vx + vw, vy + vh
    if scissor is not None:
        sx, sy, sw, sh = (float(v) for v in scissor)
        x0, y0, x1, y1 = max(x0, sx), max(y0, sy), min(x1, sx + sw), min(y1, sy + sh)
    if x1 <= x0 or y1 <= y0 or vw <= 0 or vh <= 0:
        return None
    nx0 = (x0 - margin - vx) / vw * 2.0 - 1.0
    nx1 = (x1 + margin - vx) / vw * 2.0 - 1.0
    ny0 = (y0 - margin - vy) / vh * 2.0 - 1.0
    ny1 = (y1 + margin - vy) / vh * 2.0 - 1.0
    clip = np.array(
        [
            [1.0, 0.0, 0.0, -nx0],  # x >= nx0 w
            [-1.0, 0.0, 0.0, nx1],  # x <= nx1 w
            [0.0, 1.0, 0.0, -ny0],
            [0.0, -1.0, 0.0, ny1],
            [0.0, 0.0, 1.0, 1.0],  # z >= -w (near)
            [0.0, 0.0, -1.0, 1.0],  # z <= w (far)
        ]
    )
    return clip @ np.asarray(mvp, np.float64)


def box_corners(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """The 8 corners of the box (lo, hi) as homogeneous points (8, 4)."""
    return np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])


def box_inside(planes: np.ndarray, corners: np.ndarray) -> bool:
    """Whether the box with `corners` (box_corners) lies wholly inside every half-space (then nothing
    can be left out)."""
    return bool((corners @ planes.T >= 0.0).all())


def visible_triangles(pos: np.ndarray, tris: np.ndarray, planes: np.ndarray) -> np.ndarray:
    """Boolean mask over `tris` (T, 3) of the triangles not wholly outside one of `planes` (6, 4),
    for vertex positions `pos` (N, 3)."""
    d = pos @ planes[:, :3].T.astype(pos.dtype) + planes[:, 3].astype(pos.dtype)
    code = np.packbits(d < 0.0, axis=1, bitorder="little")[:, 0]  # which half-spaces each vertex is outside of
    return (code[tris[:, 0]] & code[tris[:, 1]] & code[tris[:, 2]]) == 0

"""The triangles a draw leaves out (chainsim.game.render.culling) are exactly those wholly outside one side
of the drawn region, checked against the clip coordinates of each corner on random meshes, cameras
and scissor boxes: none that could put a pixel in the box is ever left out."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from chainsim.game.render import culling


def _perspective(fov: float, aspect: float, near: float, far: float) -> np.ndarray:
    f = 1.0 / np.tan(np.radians(fov) / 2.0)
    return np.array(
        [
            [f / aspect, 0, 0, 0],
            [0, f, 0, 0],
            [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)],
            [0, 0, -1, 0],
        ]
    )


def _rigid(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    m = np.eye(4)
    m[:3, :3] = q * np.sign(np.linalg.det(q))
    m[:3, 3] = rng.normal(0.0, 3.0, 3)
    return m


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), w=st.integers(8, 400), h=st.integers(8, 400), box=st.booleans())
def test_left_out_triangles_are_wholly_outside_one_side(seed, w, h, box):
    rng = np.random.default_rng(seed)
    pos = rng.normal(0.0, 4.0, (300, 3)).astype(np.float32)
    tris = rng.integers(0, len(pos), (900, 3))
    mvp = _perspective(rng.uniform(20, 90), w / h, rng.uniform(0.05, 1.0), rng.uniform(20, 60)) @ _rigid(rng)
    viewport = (int(rng.integers(0, 50)), int(rng.integers(0, 50)), w, h)
    scissor = None
    if box:
        x0, y0 = rng.integers(0, w), rng.integers(0, h)
        scissor = (
            viewport[0] + int(x0),
            viewport[1] + int(y0),
            int(rng.integers(1, w - x0 + 1)),
            int(rng.integers(1, h - y0 + 1)),
        )
    planes = culling.region_planes(mvp, viewport, scissor, margin=0.0)
    keep = culling.visible_triangles(pos, tris, planes)

    # the reference: each corner's clip coordinates against the scissor box's edges in NDC
    clip = np.c_[pos.astype(np.float64), np.ones(len(pos))] @ mvp.T
    x, y, z, cw = clip.T
    vx, vy, vw, vh = viewport
    sx, sy, sw, sh = scissor or viewport
    nx0, nx1 = (sx - vx) / vw * 2 - 1, (sx + sw - vx) / vw * 2 - 1
    ny0, ny1 = (sy - vy) / vh * 2 - 1, (sy + sh - vy) / vh * 2 - 1
    outside = np.stack([x < nx0 * cw, x > nx1 * cw, y < ny0 * cw, y > ny1 * cw, z < -cw, z > cw], axis=1)
    wholly = outside[tris].all(axis=1).any(axis=1)  # all three corners beyond one side
    # rounding may keep a triangle that touches a side; it never leaves out one that reaches inside
    assert not (~keep & ~wholly).any()
    assert np.count_nonzero(keep & wholly) <= 2

    # any point of a kept-out triangle lies outside the region (sampled: corners, centroid, edge midpoints)
    bary = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1 / 3, 1 / 3, 1 / 3], [0.5, 0.5, 0], [0, 0.5, 0.5]])
    pts = np.einsum("sk,tkc->tsc", bary, clip[tris])
    px, py, pz, pw = np.moveaxis(pts, -1, 0)
    inside = (pw > 0) & (px > nx0 * pw) & (px < nx1 * pw) & (py > ny0 * pw) & (py < ny1 * pw) & (np.abs(pz) < pw)
    assert not (inside.any(axis=1) & ~keep).any()


def test_a_box_inside_the_region_leaves_nothing_out():
    mvp = _perspective(60, 1.0, 0.1, 100) @ np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -10.0], [0, 0, 0, 1]])
    planes = culling.region_planes(mvp, (0, 0, 100, 100))
    assert culling.box_inside(planes, culling.box_corners(np.array([-1.0] * 3), np.array([1.0] * 3)))
    assert not culling.box_inside(planes, culling.box_corners(np.array([-50.0] * 3), np.array([1.0] * 3)))
    assert culling.region_planes(mvp, (0, 0, 100, 100), (200, 200, 10, 10)) is None  # box off the viewport

"""A drag through ChainMailBody.move (the path every tool takes) against the plain-Python reference: each
frame moves the grabbed element further from the shape the frame before left, on float64 and float32
bodies, with and without anchors, and with drags that carry the whole body (where the breadth-first
kernel stops as soon as every element has moved)."""

from __future__ import annotations

import numpy as np
from cascade_reference import MESH_KINDS, random_mesh, ref_cascade
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from chainsim.systems.engine.bodies.chainmail import ChainMailBody
from chainsim.systems.engine.kernels.chainmail import material_arrays

SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@SETTINGS
@given(
    st.integers(0, 2**32 - 1),
    st.sampled_from(MESH_KINDS),
    st.sampled_from([(1.0, 1.0, 0.0), (0.841577, 1.08347, 0.074934), (0.122418, 1.426819, 0.439017)]),
    st.sampled_from([np.float64, np.float32]),
    st.booleans(),
    st.sampled_from([0.2, 1.0, 4.0]),
)
def test_drag_frames_match_the_reference(seed, kind, material, dtype, anchored, step):
    rng = np.random.default_rng(seed)
    dim = {"planar": 2, "surface": 3, "volume": 3}.get(kind) or int(rng.integers(1, 4))
    rest, links = random_mesh(kind, dim, rng, size=int(rng.integers(3, 7)))
    n = len(rest)
    rest = rest.astype(dtype)
    fixed = rng.random(n) < 0.1 if anchored else None
    body = ChainMailBody(rest, links, *material, dtype=dtype, fixed=fixed)
    amin, amax, beta = material_arrays(len(links), *material)
    grab = int(rng.integers(n))
    direction = rng.normal(size=dim)
    ref = rest.copy()
    alive = np.ones(len(links), bool)
    for frame in range(1, 6):
        target = (rest[grab].astype(np.float64) + frame * step * direction).reshape(1, dim)
        changed = body.move([grab], target)
        ref, ref_order, ref_sponsor = ref_cascade(
            rest, ref, links, alive, amin, amax, beta, np.array([grab]), target.astype(dtype), fixed
        )
        np.testing.assert_array_equal(body.positions, ref)
        np.testing.assert_array_equal(body.last_order, ref_order)
        np.testing.assert_array_equal(body.last_sponsor, ref_sponsor)
        np.testing.assert_array_equal(changed, ref_order)


def test_a_drag_that_carries_the_whole_body_moves_every_element_once():
    rest, links = random_mesh("volume", 3, np.random.default_rng(3), size=6)
    body = ChainMailBody(rest, links, 1.0, 1.0, 0.0)
    for frame in range(1, 4):
        changed = body.move([0], rest[0] + frame * np.array([0.5, 0.2, 0.1]))
        assert len(changed) == len(rest) and len(np.unique(changed)) == len(rest)
        np.testing.assert_allclose(body.positions - rest, np.tile(frame * np.array([0.5, 0.2, 0.1]), (len(rest), 1)))


def test_a_held_element_stays_while_another_is_dragged():
    rest, links = random_mesh("surface", 3, np.random.default_rng(5), size=6)
    body = ChainMailBody(rest, links, 0.8, 1.2, 0.1)
    body.grab([0], rest[0] + 0.5)
    held = body.positions[0].copy()
    for frame in range(1, 4):
        body.move([len(rest) - 1], rest[-1] + frame * 1.5)
        np.testing.assert_array_equal(body.positions[0], held)
    assert set(body.held.tolist()) == {0, len(rest) - 1}


def test_an_anchor_set_on_the_body_between_frames_holds_from_the_next_frame():
    """body.fixed is the anchors' own array: a tool that pins an element mid-drag (body.fixed[i] = True) is
    obeyed from the next frame on, though the drag started with no anchor at all."""
    rest, links = random_mesh("volume", 3, np.random.default_rng(5), size=6)
    body = ChainMailBody(rest, links, 0.95, 1.05, 0.02)
    far = int(np.argmax(np.sum((rest - rest[0]) ** 2, axis=1)))
    step = np.array([2.0, 1.5, 1.0])
    body.move([0], rest[0] + step)
    assert far in body.moved  # the whole block followed the first frame
    body.fixed[far] = True
    held = body.positions[far].copy()
    for frame in range(2, 5):
        changed = body.move([0], rest[0] + frame * step)
        assert far not in changed
        np.testing.assert_array_equal(body.positions[far], held)

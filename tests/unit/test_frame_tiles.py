"""The browser trainer's tiled frames (chainsim.game.server.frame_tiles): the runs sent, drawn over the
picture the page has, give the new picture; nothing changed sends nothing; the payload reads back."""

from __future__ import annotations

import io

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from chainsim.game.server.frame_tiles import TILE, changed_runs, pack_frame, unpack_frame


@st.composite
def pictures(draw):
    """A picture and a copy with a few rectangles changed (sizes not multiples of the tile)."""
    # widths of whole 8-byte words take the word-wise comparison, the others the byte-wise one
    h, w = draw(st.integers(1, 300)), draw(st.one_of(st.integers(1, 400), st.integers(1, 50).map(lambda k: 8 * k)))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    prev = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    cur = prev.copy()
    for _ in range(draw(st.integers(0, 5))):
        y0, x0 = draw(st.integers(0, h - 1)), draw(st.integers(0, w - 1))
        y1, x1 = draw(st.integers(y0 + 1, h)), draw(st.integers(x0 + 1, w))
        cur[y0:y1, x0:x1, draw(st.integers(0, 2))] ^= np.uint8(draw(st.integers(1, 255)))
    return prev, cur


@settings(max_examples=150, deadline=None)
@given(pictures())
def test_the_runs_drawn_over_the_last_picture_give_the_new_one(pair):
    prev, cur = pair
    runs = changed_runs(prev, cur)
    shown = prev.copy()
    for x, y, w, h in runs:
        assert 0 <= x and 0 <= y and x + w <= cur.shape[1] and y + h <= cur.shape[0] and w > 0 and h > 0
        shown[y : y + h, x : x + w] = cur[y : y + h, x : x + w]
    assert np.array_equal(shown, cur)
    if np.array_equal(prev, cur):
        assert runs == []
    # a run covers whole tiles that changed: never a tile row it does not touch
    changed = sum(w * h for _, _, w, h in runs)
    assert changed <= cur.shape[0] * cur.shape[1]


def test_a_small_change_sends_a_small_part_and_a_first_picture_is_sent_whole():
    prev = np.zeros((800, 1280, 3), np.uint8)
    cur = prev.copy()
    cur[400:410, 600:700] = 255  # a dial's needle, a line of text
    runs = changed_runs(prev, cur)
    assert sum(w * h for _, _, w, h in runs) <= 2 * TILE * 3 * TILE
    assert changed_runs(None, cur) == [(0, 0, 1280, 800)]
    assert changed_runs(np.zeros((10, 10, 3), np.uint8), cur) == [(0, 0, 1280, 800)]


def test_the_payload_reads_back_and_its_runs_decode_to_the_picture():
    rng = np.random.default_rng(3)
    cur = np.repeat(np.repeat(rng.integers(0, 256, (25, 40, 3), dtype=np.uint8), 32, 0), 32, 1)  # 800x1280
    runs = [(0, 0, 1280, 64), (128, 192, 320, 64)]
    number, seq, got = unpack_frame(pack_frame(7, 2**32 + 5, cur, runs, "jpeg", 95))
    assert (number, seq) == (7, 5)
    assert [r[:4] for r in got] == runs
    for x, y, w, h, data in got:
        im = np.asarray(Image.open(io.BytesIO(data)).convert("RGB"), int)
        assert im.shape == (h, w, 3)
        assert np.abs(im - cur[y : y + h, x : x + w]).mean() < 4.0

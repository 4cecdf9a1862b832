"""Leaving the real window never loses work silently (under Xvfb, driven by xdotool): Esc on the
sign-in page closes the page as the page box's banner says, and the program stays open; Esc with an
attempt in progress asks first (a page over the view) and keeps the window open; a second Esc then quits.

Runs where Xvfb and xdotool are installed (CI installs them); skipped elsewhere."""

from __future__ import annotations

import subprocess
import time

import pytest
from test_trainee_session import Session, landmark_pixels, needs_x


@pytest.mark.slow
@needs_x
def test_esc_closes_the_sign_in_page_and_asks_before_unsaved_work_is_lost(tmp_path):
    lm = landmark_pixels()
    s = Session(tmp_path)
    try:
        s.key("Escape", wait=1.5)  # the sign-in page: closed, the trainer stays open
        assert s.app.poll() is None
        s.key("Escape", wait=1.5)  # the help page under it: closed too
        assert s.app.poll() is None
        s.click(*lm[0], wait=1.5)  # an attempt begins: landmark 1 placed, nothing saved
        placed = s.shot("placed")
        s.key("Escape", wait=1.5)
        assert s.app.poll() is None  # asked, not quit
        asked = s.shot("asked")
        s.key("space", wait=1.0)  # any other key: back to the attempt
        assert s.app.poll() is None
        s.key("Escape", wait=1.0)
        subprocess.run(["xdotool", "key", "--window", s.wid, "Escape"], env=s.env, check=False)
        time.sleep(2.0)
    finally:
        out = s.close()
    assert s.app.returncode == 0, out
    # the question is a page over the face while it asks
    assert (abs(asked[200:500, 100:600] - placed[200:500, 100:600]).max(axis=2) > 60).mean() > 0.2

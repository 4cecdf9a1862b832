"""The trainer window is never opened larger than the screen (a 1024x768 screen gets a 1024x768 window
whose controller is all in sight)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from chainsim.game.trainer.window import fit_screen


def _pyglet(width: int, height: int):
    screen = SimpleNamespace(width=width, height=height)
    display = SimpleNamespace(get_default_screen=lambda: screen)
    return SimpleNamespace(display=SimpleNamespace(get_display=lambda: display))


@pytest.mark.parametrize(
    ("screen", "asked", "opened"),
    [
        ((1024, 768), (1280, 800), (1024, 768)),
        ((1920, 1080), (1280, 800), (1280, 800)),
        ((1280, 720), (1280, 800), (1280, 720)),
    ],
)
def test_the_window_is_no_larger_than_the_screen(screen, asked, opened):
    assert fit_screen(_pyglet(*screen), *asked) == opened


def test_a_display_that_cannot_say_its_size_gets_the_size_asked_for():
    def fails():
        raise RuntimeError("no screen")

    broken = SimpleNamespace(display=SimpleNamespace(get_display=fails))
    assert fit_screen(broken, 1280, 800) == (1280, 800)

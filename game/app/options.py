"""Options the command line, the window and the benchmarks share: window sizes and the user's record settings."""

from __future__ import annotations

import argparse


def window_size(text: str) -> tuple[int, int]:
    """argparse type: WIDTHxHEIGHT in pixels, each 1..16384."""
    try:
        w, h = (int(x) for x in text.lower().split("x"))
        if w <= 0 or h <= 0 or w > 16384 or h > 16384:
            raise ValueError
        return w, h
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT such as 1280x800, got {text!r}") from None


def user_settings(args) -> dict:
    """Settings a user gives on the command line (records database or server, class, trainee)."""
    out = {}
    pairs = (("db", "db"), ("records", "records"), ("class", "class_name"), ("trainee", "trainee"), ("model", "model"))
    for key, attr in pairs:
        v = getattr(args, attr, None)
        if v is not None:
            out[key] = v
    return out


MODEL_FLAG_HELP = "deformation model for every soft body: chainmail, xpbd, projective or auto (overrides the pack)"
MODEL_FLAG_CHOICES = ("chainmail", "xpbd", "projective", "auto")

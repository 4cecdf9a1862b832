"""Argument types of the command line: every number a flag takes is parsed and bounded here.

One set of argparse types for every command and benchmark, so a flag can never hand the program a
NaN, an inf, a negative count or a count that would run for ever: `real(lo, hi)` (finite floats in
a range, default +-MAX_COORD), `count(lo, hi)` (whole numbers in a range) and `size` (WIDTHxHEIGHT
within MAX_PIXELS). The bounds come from chainsim.systems.engine.limits (docs/limits.md). A bad value is
argparse's one-line usage error, exit 2. (Names of classes and trainees are the records' own type:
chainsim.game.trainer.options.name.)

`NEGATIVE_NUMBER` is what the parser takes for a negative number rather than an option, so
`--to -1e3 0 0` works (argparse on its own knows only -12 and -1.5).
"""

from __future__ import annotations

import argparse
import math
import re
from collections.abc import Callable

from chainsim.systems.engine import limits

NEGATIVE_NUMBER = re.compile(r"^-(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?$|^-(?:inf|infinity|nan)$", re.I)


def _g(x: float) -> str:
    return f"{x:g}"


def real(
    lo: float = -limits.MAX_COORD,
    hi: float = limits.MAX_COORD,
    *,
    low_open: bool = False,
    high_open: bool = False,
    what: str = "",
) -> Callable[[str], float]:
    """A finite number in [lo, hi]; low_open / high_open leave out an end; `what` names it in messages."""
    what = f"{what} " if what else ""

    def parse(text: str) -> float:
        try:
            x = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text[:40]!r}") from None
        if not math.isfinite(x):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text[:40]!r}")
        if x < lo or x > hi or (low_open and x == lo) or (high_open and x == hi):
            left, right = "(" if low_open else "[", ")" if high_open else "]"
            raise argparse.ArgumentTypeError(f"must be {what}in {left}{_g(lo)}, {_g(hi)}{right}, got {text[:40]}")
        return x

    parse.__name__ = "number"  # argparse names the type in its messages
    return parse


def count(lo: int = 0, hi: int = limits.MAX_INT) -> Callable[[str], int]:
    """A whole number in [lo, hi]."""

    def parse(text: str) -> int:
        t = text.strip()
        if len(t) > 40:
            raise argparse.ArgumentTypeError(f"expected a whole number from {lo} to {hi}, got a {len(t)}-digit value")
        try:
            v = int(t)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a whole number, got {text[:40]!r}") from None
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"must be from {lo} to {hi}, got {v}")
        return v

    parse.__name__ = "whole number"
    return parse


def size(text: str) -> tuple[int, int]:
    """WIDTHxHEIGHT, each from 1 to MAX_PIXELS."""
    try:
        w, h = (int(x) for x in text.lower().split("x"))
        if not (0 < w <= limits.MAX_PIXELS and 0 < h <= limits.MAX_PIXELS):
            raise ValueError
        return w, h
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT such as 1280x800 (each 1 to {limits.MAX_PIXELS}), got {text[:40]!r}"
        ) from None


# the ranges the commands share
steps = count(0, limits.MAX_STEPS)
relax = count(0, limits.MAX_RELAX)
repeat = count(0, limits.MAX_REPEAT)
frames = count(1, limits.MAX_FRAMES)
element = count(0, limits.MAX_VERTICES - 1)
dt = real(limits.MIN_DT, limits.MAX_DT)
coordinate = real()

"""The one progress facility for long jobs (study, calibration, benchmarks, pack preparation, compilation).

A thin wrapper over tqdm so every long job looks the same: a bar on stderr that ends its line,
quiet when the `chainsim` logger is above INFO (`-q`) or when CHAINSIM_PROGRESS=0.
"""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

from tqdm import tqdm

T = TypeVar("T")


def _disabled() -> bool:
    return os.environ.get("CHAINSIM_PROGRESS", "1") == "0" or not logging.getLogger("chainsim").isEnabledFor(
        logging.INFO
    )


def progress(
    iterable: Iterable[T] | None = None, *, total: int | None = None, desc: str = "", unit: str = "it"
) -> tqdm:
    """A progress bar over `iterable` (or a manual one with `total`, advanced by `.update(n)`)."""
    return tqdm(
        iterable,
        total=total,
        desc=desc,
        unit=unit,
        file=sys.stderr,
        leave=True,
        mininterval=0.5,
        dynamic_ncols=True,
        disable=_disabled(),
    )


def track(iterable: Iterable[T], desc: str, total: int | None = None) -> Iterator[T]:
    """Iterate with a bar; the bar always closes, even when the loop is left early."""
    bar = progress(iterable, total=total, desc=desc)
    try:
        yield from bar
    finally:
        bar.close()

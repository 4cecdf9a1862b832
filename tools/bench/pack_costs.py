"""Frame cost of every built-in pack broken down by system ("model only what a scene requires"):
each pack is stepped headless through chainsim.game.trainer.headless.run_pack and its per-system timings kept."""

from __future__ import annotations

import logging

from chainsim.game.packs.pack import discover
from chainsim.game.trainer.headless import run_pack

logger = logging.getLogger(__name__)


def measure(steps: int = 120) -> tuple[list[dict], str]:
    """Summaries of all built-in packs (those that fail to run are named in the note)."""
    summaries, failed = [], []
    for found in discover():
        if found.source != "builtin":
            continue
        logger.info(f"pack {found.name}: {steps} steps")
        try:
            summaries.append(run_pack(found.name, steps, save="a cost measurement saves nothing"))
        except Exception as e:  # one broken pack must not sink the report
            failed.append(f"{found.name}: {type(e).__name__}: {e}")
    note = (
        f"Each pack stepped {steps} fixed steps headless (no rendering); wall-clock ms per "
        "system call on a shared machine."
    )
    if failed:
        note += " Packs that could not be run: " + "; ".join(failed)
    return summaries, note

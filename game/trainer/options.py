"""Options the command line, the window and the benchmarks share: window sizes and the user's record settings.

Numbers are typed by chainsim.systems.engine.argtypes (finite, bounded: docs/limits.md); class and trainee
names by `name` here, which takes them as the records store does (1 to MAX_NAME_LENGTH printable
characters, no control or invisible characters), so a bad name is refused before anything runs.
"""

from __future__ import annotations

import argparse

from chainsim.game.records.validate import clean_name
from chainsim.systems.engine import argtypes
from chainsim.systems.engine.errors import UserError
from chainsim.systems.tissue.deformable import MODEL_CHOICES

#: argparse type: WIDTHxHEIGHT in pixels, each 1..MAX_PIXELS
window_size = argtypes.size


def name(kind: str):
    """argparse type: a class or trainee name, checked as the records store checks it."""

    def parse(text: str) -> str:
        try:
            return clean_name(kind, text)
        except UserError as e:
            raise argparse.ArgumentTypeError(str(e)) from None

    parse.__name__ = f"{kind} name"
    return parse


def add_records_arguments(p: argparse.ArgumentParser) -> None:
    """--db, --records, --class and --trainee, for commands whose procedures save attempts."""
    p.add_argument("--db", metavar="PATH", help="trainee records database (procedures that save attempts)")
    p.add_argument(
        "--records", metavar="URL", help="save attempts to this records server (queued in --db when offline)"
    )
    p.add_argument(
        "--class", dest="class_name", type=name("class"), metavar="NAME", help="class the attempt is saved under"
    )
    p.add_argument("--trainee", type=name("trainee"), metavar="NAME", help="trainee the attempt is saved under")


def user_settings(args) -> dict:
    """Settings a user gives on the command line (records database or server, class, trainee, model, fluoro-first)."""
    out = {}
    pairs = (
        ("db", "db"),
        ("records", "records"),
        ("class", "class_name"),
        ("trainee", "trainee"),
        ("model", "model"),
        ("fluoro_first", "fluoro_first"),
    )
    for key, attr in pairs:
        v = getattr(args, attr, None)
        if v is not None:
            out[key] = v
    return out


MODEL_FLAG_HELP = (
    "deformation model for every soft body: chainmail, xpbd, projective, hybrid (volumes), surface "
    "(sheets) or auto (overrides the pack)"
)
MODEL_FLAG_CHOICES = MODEL_CHOICES  # one list: the pack key `model` and the flag take the same names


def add_mode_arguments(p: argparse.ArgumentParser) -> None:
    """--model and --fluoro-first, for the commands that run a pack (play, run)."""
    p.add_argument("--model", choices=MODEL_FLAG_CHOICES, help=MODEL_FLAG_HELP)
    p.add_argument(
        "--fluoro-first",
        action="store_true",
        default=None,
        help="fluoroscopy first: no target ring or distance in the needle-tip view, guide by X-ray "
        "(as the pack's [needle_procedure] fluoro_first; recorded with each attempt)",
    )


def add_device_argument(p: argparse.ArgumentParser) -> None:
    """--device, for the commands that run a needle pack (play, run): docs/haptics.md."""
    p.add_argument(
        "--device",
        metavar="NAME",
        help="drive the needle with a force-feedback device: sim (the simulated device), sim:FILE (it plays "
        "that trajectory) or a driver's name (docs/haptics.md)",
    )

"""`chainsim new-pack NAME [--dir DIR]`: scaffold a valid pack to start a new procedure from."""

from __future__ import annotations

from pathlib import Path

from chainsim.engine.errors import UserError
from chainsim.game.packs import pack as packs
from chainsim.game.packs.scaffold import create

NAME = "new-pack"
HELP = "create a new asset pack folder from a template"


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP)
    p.add_argument("name", help="pack name (letters, digits, - and _)")
    p.add_argument("--dir", default=".", help="parent folder (default: current folder)")
    p.add_argument("--title", default=None, help="human-readable title")
    return p


def run(args) -> int:

    if not Path(args.dir).is_dir():
        raise UserError(f"--dir {args.dir}: not a folder")
    root = create(args.name, Path(args.dir), args.title)
    _, problems = packs.validate(root)
    if problems:  # the template must always validate; a failure here is a bug worth reporting loudly
        raise UserError("the new pack does not validate: " + "; ".join(map(str, problems)))
    print(f"created {root} (validates clean); next: chainsim run {root} --headless --steps 120 --out runs/{args.name}")
    return 0

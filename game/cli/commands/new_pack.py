"""`chainsim new-pack NAME [--template tissue|needle|empty] [--dir DIR]`: a new pack that validates,
runs headless and plays in the window, to start a procedure or demo from (docs/making-a-pack.md)."""

from __future__ import annotations

from pathlib import Path

from chainsim.game.packs.scaffold import DEFAULT_TEMPLATE, TEMPLATES, create
from chainsim.game.trainer.headless import validate_pack
from chainsim.systems.engine.errors import UserError

NAME = "new-pack"
HELP = "create a new asset pack folder from a template"


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP)
    p.add_argument("name", help="pack name (letters, digits, - and _)")
    p.add_argument(
        "--template",
        choices=list(TEMPLATES),
        default=DEFAULT_TEMPLATE,
        help="; ".join(f"{k}: {v}" for k, v in TEMPLATES.items()),
    )
    p.add_argument("--dir", default=".", help="parent folder (default: current folder)")
    p.add_argument("--title", default=None, help="human-readable title")
    return p


def run(args) -> int:

    if not Path(args.dir).is_dir():
        raise UserError(f"--dir {args.dir}: not a folder")
    root = create(args.name, Path(args.dir), args.title, args.template)
    _, problems = validate_pack(root)  # as `chainsim validate` checks it, scenes started
    if problems:  # the template must always validate; a failure here is a bug worth reporting loudly
        raise UserError("the new pack does not validate: " + "; ".join(map(str, problems)))
    print(
        f"created {root} from the {args.template} template (validates clean); next:\n"
        f"  chainsim run {root} --headless --out runs/{args.name}\n"
        f"  chainsim play {root}"
    )
    return 0

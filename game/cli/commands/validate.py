"""`chainsim validate PATH`: every problem in a pack at once, one line each; exit 2 if any.

It reports whatever `chainsim run` would refuse: the manifest and files are checked, then each
scene is started as `run` starts it (chainsim.game.trainer.headless.validate_pack).
"""

from __future__ import annotations

import sys
from pathlib import Path

from chainsim.game.packs import pack as packs
from chainsim.game.trainer.headless import validate_pack

NAME = "validate"
HELP = "check a pack folder and report every problem"


def add_parser(sub):
    p = sub.add_parser(NAME, help=HELP)
    p.add_argument("path", help="pack folder (or its pack.toml), or the name of a known pack")
    p.add_argument("--pack-path", action="append", default=[], metavar="DIR")
    return p


def run(args) -> int:

    path = Path(args.path)
    if path.name == "pack.toml":
        path = path.parent
    if not path.exists():
        path, _ = packs.resolve(args.path, args.pack_path)
    pack, problems = validate_pack(path, args.pack_path)
    if problems:
        for p in problems:
            print(p, file=sys.stderr)
        print(f"{len(problems)} problem{'s' if len(problems) > 1 else ''} in {path}", file=sys.stderr)
        return 2
    assert pack is not None  # no problem found: validate_pack returned the pack
    m = pack.manifest
    print(
        f"{path}: ok ({m['pack']['name']}: {len(m['meshes'])} meshes, {len(m['entities'])} entities, "
        f"{len(m['scenes'])} scenes, {len(m['steps'])} steps)"
    )
    return 0

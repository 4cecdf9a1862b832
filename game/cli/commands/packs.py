"""`chainsim packs`: list the packs found and where they come from."""

from __future__ import annotations

from chainsim.game.packs import pack as packs

NAME = "packs"
HELP = "list the asset packs found and where"


def add_parser(sub):
    p = sub.add_parser(
        NAME,
        help=HELP,
        description="List packs: --pack-path folders, CHAINSIM_PACK_PATH, pip-installed (entry points), built-in.",
    )
    p.add_argument("--pack-path", action="append", default=[], metavar="DIR", help="extra folder of packs (repeatable)")
    return p


def run(args) -> int:

    found = packs.discover(args.pack_path)
    seen = set()
    rows = []
    for f in found:
        shadowed = f.name in seen
        seen.add(f.name)
        pack, problems = packs.validate(f.path, load_meshes=False, pack_paths=args.pack_path)
        if problems:
            status = (
                f"INVALID ({len(problems)} problem{'s' if len(problems) > 1 else ''}; run chainsim validate {f.path})"
            )
            scenes = ""
        else:
            assert pack is not None  # no problem found: validate returned the pack
            status = pack.manifest["pack"].get("title") or ""
            scenes = ", ".join(pack.scene_names())
        rows.append((f.name + (" (shadowed)" if shadowed else ""), f.source, str(f.path), scenes, status))
    if not rows:
        print("no packs found")
        return 0
    w = [max(len(r[i]) for r in rows) for i in range(3)]
    for r in rows:
        print(f"{r[0]:<{w[0]}}  {r[1]:<{w[1]}}  {r[2]:<{w[2]}}  {r[4]}" + (f"  [scenes: {r[3]}]" if r[3] else ""))
    return 0

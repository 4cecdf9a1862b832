"""Pack dependencies: `[pack] requires = ["prp"]` and paths into a required pack (`"prp:meshes/skull.ply"`).

A pack may name other packs it builds on; its path keys (meshes, docs pages, includes, scripts) may
then point into their folders with `PACK:PATH`. A pack still reads nothing outside its own folder and
the folders of the packs it lists itself: a path into a pack it does not list, or one that climbs out
of the folder it names, is refused by `chainsim validate`. Required packs are found where packs are
found (chainsim.game.packs.discovery), with the folder that holds the requiring pack searched first,
so packs kept side by side find each other without --pack-path. Each required pack's own `requires`
is followed too, each pack read once however many paths lead to it (linear in the number of packs,
at most MAX_REQUIRED_PACKS): a missing pack anywhere in the chain, or a cycle, is one problem line.

Only the required packs' files are read, never their manifests' tables: a pack that requires `prp`
gets prp's meshes by naming them, not prp's entities or anatomy.
"""

from __future__ import annotations

import re
from pathlib import Path

from chainsim.game.packs.discovery import ENV_PATH, MANIFEST, NAME_RE, Found, discover, scan
from chainsim.systems.engine import datafile, limits
from chainsim.systems.engine.errors import UserError

#: `PACK:PATH`: a pack name (as NAME_RE), a colon, a path inside that pack's folder
REF_RE = re.compile(r"^([A-Za-z0-9][A-Za-z0-9_-]*):(.*)$", re.S)


def split_ref(rel: str) -> tuple[str, str]:
    """'prp:meshes/skull.ply' -> ('prp', 'meshes/skull.ply'); a path of the pack itself -> ('', rel)."""
    m = REF_RE.match(rel)
    return (m.group(1), m.group(2)) if m else ("", rel)


def requires_of(folder: Path) -> list[str]:
    """The `[pack] requires` list of the pack in `folder`, read as data (an unreadable manifest: none)."""
    try:
        text = datafile.read_text(folder / MANIFEST, max_bytes=limits.MAX_MANIFEST_BYTES, what="manifest")
        req = datafile.parse_toml(text, MANIFEST).get("pack", {}).get("requires", [])
    except (UserError, AttributeError):
        return []
    return [r for r in req if isinstance(r, str)] if isinstance(req, list) else []


def candidates(root: Path, pack_paths=()) -> dict[str, Path]:
    """Every pack a requirement may name: name -> folder, the first found winning (the folder holding
    `root` first, then the usual discovery order)."""
    found: list[Found] = scan(Path(root).resolve().parent, "beside")
    found.extend(discover(pack_paths))
    out: dict[str, Path] = {}
    for f in found:
        out.setdefault(f.name, f.path)
    return out


def resolve_requires(root: Path, name: str, requires: list[str], pack_paths=()) -> tuple[dict[str, Path], list[str]]:
    """The folders of the packs `requires` lists (name -> folder) and a message per problem: a name
    that is not a pack name, a pack not found (here or further down the chain), a cycle."""
    if not requires:
        return {}, []
    known = candidates(root, pack_paths)
    problems: list[str] = []
    deps: dict[str, Path] = {}
    for req in requires:
        if not NAME_RE.match(req) or len(req) > limits.MAX_KEY_LENGTH:
            problems.append(f"'{req[:60]}' is not a pack name (letters, digits, - and _)")
        elif req == name:
            problems.append(f"'{req}' is this pack itself: a pack cannot require itself")
        elif req not in known:
            problems.append(_not_found(req, known))
        else:
            deps[req] = known[req]
    msg = _check_below(name, list(deps), known)
    if msg:
        problems.append(msg)
    return deps, problems


def _check_below(name: str, direct: list[str], known: dict[str, Path]) -> str:
    """The packs below the direct requirements, each read once (depth first, without recursion): the
    first missing pack, cycle, chain deeper than MAX_NESTING or graph over MAX_REQUIRED_PACKS, or "".

    A pack reached again by another path is not read again, so a diamond of n packs costs n reads,
    not one per path (which doubles with every level)."""
    state: dict[str, str] = {name: "open"}  # pack -> "open" (on the current chain) or "done"
    chain = [name]
    todo = [iter(direct)]  # per pack on the chain: the requirements not yet followed
    while todo:
        req = next(todo[-1], None)
        if req is None:
            state[chain.pop()] = "done"
            todo.pop()
            continue
        if state.get(req) == "done":
            continue
        if state.get(req) == "open":
            cyc = chain[chain.index(req) :] + [req]
            return f"{' -> '.join(cyc)} is a cycle (packs cannot require one another in a ring)"
        if req not in known:
            return f"'{chain[-1]}' requires {_not_found(req, known)}"
        if len(chain) >= limits.MAX_NESTING:
            return f"the chain {' -> '.join(chain[:8])} -> ... is too deep (over {limits.MAX_NESTING} packs)"
        if len(state) > limits.MAX_REQUIRED_PACKS:
            return (
                f"builds on more than {limits.MAX_REQUIRED_PACKS} packs through its requirements "
                "(MAX_REQUIRED_PACKS, docs/limits.md)"
            )
        state[req] = "open"
        chain.append(req)
        todo.append(iter(requires_of(known[req])))
    return ""


def _not_found(req: str, known: dict[str, Path]) -> str:
    return (
        f"pack '{req}' not found (known packs: {', '.join(sorted(known)) or 'none'}; "
        f"add folders with --pack-path or {ENV_PATH}, or keep the packs side by side)"
    )

"""Finding packs: pack folders named on the command line or in CHAINSIM_PACK_PATH, installed packs
and the built-in ones, in that order of precedence (a later pack of the same name is shadowed):

    1. folders given with --pack-path DIR (a pack folder, or a folder of pack folders)
    2. folders in the CHAINSIM_PACK_PATH environment variable (os.pathsep separated)
    3. packs installed with pip, through the `chainsim.packs` entry-point group (each entry point's
       value names a package; the pack is that package's folder, found among the distribution's
       recorded files or on sys.path and read as data: nothing is imported, so no code of an
       installed package runs)
    4. the built-in packs in `assets/`

A pack's name is read from its manifest (within the manifest limits); a manifest that cannot be read
leaves the folder's name, and `chainsim validate` says what is wrong with it.
"""

from __future__ import annotations

import os
import re
import sys
from dataclasses import dataclass
from importlib.metadata import entry_points
from pathlib import Path

from chainsim.assets import ASSETS_DIR
from chainsim.systems.engine import datafile, limits
from chainsim.systems.engine.errors import UserError, printable

BUILTIN_DIR = ASSETS_DIR
ENV_PATH = "CHAINSIM_PACK_PATH"
ENTRY_POINT_GROUP = "chainsim.packs"
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]*$")
MANIFEST = "pack.toml"


@dataclass(slots=True)
class Found:
    name: str
    path: Path
    source: str  # "builtin", "pack-path", "env", "installed"


def scan(folder: Path, source: str) -> list[Found]:
    """The packs in `folder`: itself if it holds a manifest, else its sub-folders that do."""
    out = []
    try:
        if (folder / MANIFEST).is_file():
            return [Found(_pack_name(folder), folder, source)]
        if folder.is_dir():
            for sub in sorted(folder.iterdir()):
                if (sub / MANIFEST).is_file():
                    out.append(Found(_pack_name(sub), sub, source))
    except OSError:  # an unreadable folder on a search path holds no packs we can use
        return out
    return out


def _pack_name(folder: Path) -> str:
    """[pack] name from the manifest, else the folder's name (a broken manifest is reported by validate)."""
    try:
        text = datafile.read_text(folder / MANIFEST, max_bytes=limits.MAX_MANIFEST_BYTES, what="manifest")
        name = datafile.parse_toml(text, MANIFEST).get("pack", {}).get("name")
        if isinstance(name, str) and NAME_RE.match(name) and len(name) <= limits.MAX_KEY_LENGTH:
            return name
    except (UserError, AttributeError):
        pass
    return folder.name


def _package_folders(ep) -> list[Path]:
    """Folders of the package an entry point names, found as files: never imported.

    importlib's find_spec would import every parent of a dotted name (running its __init__.py), so
    the folder is looked up among the distribution's recorded files, else on sys.path.
    """
    module = ep.value.partition(":")[0].strip()
    parts = module.split(".")
    if not module or not all(p.isidentifier() for p in parts):
        return []
    found: list[Path] = []
    dist = getattr(ep, "dist", None)
    for f in (dist.files or []) if dist is not None else []:
        if f.parts[: len(parts)] == tuple(parts) and f.name == MANIFEST and len(f.parts) == len(parts) + 1:
            found.append(Path(dist.locate_file(f)).parent)  # type: ignore[union-attr]  # files came from this dist
    if not found:  # editable installs and distributions without a RECORD
        for entry in sys.path:
            folder = Path(entry or ".").joinpath(*parts)
            if (folder / MANIFEST).is_file():
                found.append(folder)
                break
    return found


def _installed() -> list[Found]:
    out = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        for folder in _package_folders(ep):
            out.extend(scan(folder, "installed"))
    return out


def discover(pack_paths: list[str] | tuple = ()) -> list[Found]:
    """All packs found, highest precedence first; a later pack with the same name is shadowed."""
    found: list[Found] = []
    for p in pack_paths:
        path = Path(p)
        if not path.is_dir():
            raise UserError(f"--pack-path {p}: not a folder")
        found.extend(scan(path, "pack-path"))
    for p in filter(None, os.environ.get(ENV_PATH, "").split(os.pathsep)):
        found.extend(scan(Path(p), "env"))
    found.extend(_installed())
    found.extend(scan(BUILTIN_DIR, "builtin"))
    return found


def resolve(ref: str, pack_paths=()) -> tuple[Path, str | None]:
    """`PACK[/SCENE]` or a folder path -> (pack folder, scene name or None)."""
    p = Path(ref)
    if (p / "pack.toml").is_file():
        return p, None
    if p.name == "pack.toml" and p.is_file():
        return p.parent, None
    if str(p.parent) not in ("", ".") and (p.parent / "pack.toml").is_file() and not p.exists():
        return p.parent, p.name  # a pack folder path and a scene: assets/prp/fluoro
    name, _, scene = ref.partition("/")
    if (Path(name) / "pack.toml").is_file() and scene:
        return Path(name), scene
    seen: dict[str, Found] = {}
    for f in discover(pack_paths):
        seen.setdefault(f.name, f)
    if name in seen:
        return seen[name].path, (scene or None)
    known = ", ".join(sorted(seen)) or "none"
    if not NAME_RE.match(name) or (scene and Path(name).is_dir()):  # a folder path: say so, not "pack ''"
        shown = printable(ref[:200])
        if p.is_dir():
            raise UserError(f"{shown}: this folder holds no pack.toml (a pack folder holds its manifest)")
        raise UserError(
            f"pack folder '{shown}' not found; expected a pack folder, its pack.toml, or a pack name "
            f"(PACK or PACK/SCENE; known packs: {known})"
        )
    raise UserError(f"pack '{name}' not found; known packs: {known} (add folders with --pack-path or {ENV_PATH})")

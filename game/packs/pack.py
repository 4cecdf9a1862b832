"""Asset packs: the public face of finding, validating and loading them.

A pack is a folder with `pack.toml`, meshes and docs. Packs are data only: nothing in a pack is
ever imported or executed. This module holds `validate` and `load`; the parts live beside it:

    discovery   where packs are found (--pack-path, CHAINSIM_PACK_PATH, installed, built-in)
    model       the loaded Pack, its meshes and files
    checks      the per-part checks `validate` runs, and the Problem lines it reports
    requires    packs a pack builds on (`[pack] requires`) and `PACK:PATH` paths into them
    schema      the declaration of every manifest section and key

Validation collects every problem at once, each as `file:line: key.path: what is wrong`; every
value is bounded (docs/limits.md). Starting each scene the way `run` does, so that whatever `run`
refuses `chainsim validate` reports first, is the app's part: chainsim.game.trainer.headless.validate_pack.
"""

from __future__ import annotations

from pathlib import Path

from chainsim.components.registry import load_all
from chainsim.game.packs import validation as checks
from chainsim.game.packs.discovery import (
    BUILTIN_DIR,
    ENTRY_POINT_GROUP,
    ENV_PATH,
    MANIFEST,
    NAME_RE,
    Found,
    discover,
    resolve,
)
from chainsim.game.packs.model import PRESET_FILE, Pack, build_mesh, material_presets
from chainsim.game.packs.validation import PackError, Problem, Validator, problem_at
from chainsim.systems import manifest_modules

__all__ = [
    "BUILTIN_DIR",
    "ENTRY_POINT_GROUP",
    "ENV_PATH",
    "MANIFEST",
    "NAME_RE",
    "PRESET_FILE",
    "Found",
    "Pack",
    "PackError",
    "Problem",
    "build_mesh",
    "discover",
    "load",
    "material_presets",
    "problem_at",
    "resolve",
    "validate",
]


def validate(root: Path, *, load_meshes: bool = True, pack_paths=()) -> tuple[Pack | None, list[Problem]]:
    """Validate a pack folder's manifest and files; returns (pack or None, every problem found).

    `pack_paths` (--pack-path folders) are searched for the packs it requires (chainsim.game.packs.requires).

    This checks everything that needs no running App; chainsim.game.trainer.headless.validate_pack
    also starts each scene as `run` does (what `chainsim validate` reports).
    """
    load_all(manifest_modules())
    root = Path(root)
    if not root.is_dir():
        return None, [Problem(str(root), "", "not a folder")]
    v = Validator(root, pack_paths)
    raw = checks.read_manifest(v)
    if raw is None:
        return None, v.problems
    man = checks.check_sections(v, raw)
    checks.check_pack_table(v, man)
    meshes = checks.check_meshes(v, man, load_meshes)
    checks.check_files(v, man)
    man["entities"] = checks.check_entities(v, raw, man)
    checks.check_scenes(v, man)
    checks.check_layouts(v, man)
    checks.check_steps(v, man)
    checks.check_procedure(v, man)
    if v.problems:
        return None, v.problems
    return Pack(root=root, manifest=man, texts=v.texts, origin=v.origin, deps=v.deps, _meshes=meshes), []


def load(root: Path, pack_paths=()) -> Pack:
    """Validate (meshes loaded, as `validate` does) and return the pack, or raise PackError listing every problem.

    The scenes are not started here: the caller starts the one it runs.
    """
    pack, problems = validate(root, pack_paths=pack_paths)
    if problems:
        raise PackError(problems)
    assert pack is not None  # validate returns the pack whenever it found no problem
    return pack

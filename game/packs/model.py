"""The loaded pack: its converted manifest, its files (kept inside the pack folder) and its meshes.

`Pack` is what `chainsim.game.packs.pack.validate` returns; `build_mesh` turns a [meshes] entry into
a MeshData in millimetres (chainsim.systems.engine.meshes checks the file and the result against the mesh
limits); `inside` keeps a path inside one folder and `locate` keeps every path a manifest names inside
its pack or, written `PACK:PATH`, inside a pack it requires (chainsim.game.packs.requires);
`material_presets` reads the calibrated ChainMail materials a [materials] entry may name.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from chainsim.assets import ASSETS_DIR
from chainsim.components.registry import SECTION_STYLE
from chainsim.game.packs import declarations as ms
from chainsim.game.packs.requires import split_ref
from chainsim.systems.engine.errors import UserError
from chainsim.systems.engine.meshes import MeshData, check_mesh, load_file, primitive
from chainsim.systems.engine.reorder import reorder_mesh

PRESET_FILE = ASSETS_DIR / "presets" / "materials.toml"
PRESET_KEYS = {"alpha_min": "alpha_min", "alpha_max": "alpha_max", "beta": "beta", "relax": "relax_iterations"}


def inside(root: Path, rel: str) -> Path | None:
    """The resolved path of `rel` if it stays inside `root` (symlinks followed), else None."""
    if os.path.isabs(rel):
        return None
    try:
        target = (root / rel).resolve()
        target.relative_to(root.resolve())
    except (ValueError, OSError):  # outside the pack, a NUL byte, a symlink loop
        return None
    return target


def locate(root: Path, deps: dict[str, Path], rel: str) -> tuple[Path | None, str]:
    """(the resolved file, "") for a path a manifest names, or (None, why it is refused).

    A plain path stays inside `root`; `PACK:PATH` stays inside the folder of PACK, which must be one
    of `deps` (the packs this pack requires)."""
    dep, sub = split_ref(rel)
    if not dep:
        p = inside(root, rel)
        if p is None:
            return None, f"'{rel}' escapes the pack folder (paths must stay inside {root.name}/)"
        return p, ""
    if dep not in deps:
        listed = ", ".join(sorted(deps)) or "none"
        return None, f"'{rel}' points into pack '{dep}', which [pack] requires does not list (requires: {listed})"
    p = inside(deps[dep], sub)
    if p is None:
        return None, f"'{rel}' escapes the folder of pack '{dep}' (paths must stay inside {deps[dep].name}/)"
    return p, ""


@dataclass
class Pack:
    """A validated pack: converted manifest sections and lazily loaded meshes."""

    root: Path
    manifest: dict[str, Any]
    texts: dict[str, str] = field(default_factory=dict)
    origin: dict[str, str] = field(default_factory=dict)  # "section.name" -> the manifest file defining it
    deps: dict[str, Path] = field(default_factory=dict)  # required pack name -> its folder
    _meshes: dict[str, MeshData] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.manifest["pack"]["name"]

    def section(self, name: str) -> Any:
        return self.manifest.get(name, {} if SECTION_STYLE[name] != "list" else [])

    def mesh(self, name: str) -> MeshData:
        if name not in self._meshes:
            self._meshes[name] = build_mesh(self.root, name, self.manifest["meshes"][name], self.deps)
        return self._meshes[name]

    def display_mesh(self, name: str) -> MeshData:
        """What the renderer draws for mesh `name`: its `display` file (a decimated copy, for speed
        in software rendering) where it has one, else the mesh itself. Its vertices are read as
        stored: a copy keeps a crease (a flat cap) by giving the faces on each side their own."""
        spec = self.manifest["meshes"][name]
        if not spec.get("display") or spec.get("primitive"):
            return self.mesh(name)
        key = f"display:{name}"
        if key not in self._meshes:
            as_stored = {**spec, "path": spec["display"], "reorder": False, "merge_vertices": False}
            self._meshes[key] = build_mesh(self.root, name, as_stored)
        return self._meshes[key]

    def scene_names(self) -> list[str]:
        return list(self.section("scenes"))

    def scene(self, name: str | None = None) -> tuple[str, dict]:
        scenes = self.section("scenes")
        if not scenes:
            return "main", {
                "entities": [],
                "layout": next(iter(self.section("layouts")), ""),
                "description": "",
                "script": "",
            }
        if name is None:
            name = self.manifest["pack"].get("default_scene") or next(iter(scenes))
        if name not in scenes:
            raise UserError(f"pack '{self.name}' has no scene '{name}'; scenes: {', '.join(scenes)}")
        return name, scenes[name]

    def doc_text(self, name: str) -> str:
        return self.file(self.section("docs")[name]["path"]).read_text(encoding="utf-8")

    def file(self, rel: str) -> Path:
        """A file the manifest names: in this pack, or `PACK:PATH` in a pack it requires."""
        p, why = locate(self.root, self.deps, rel)
        if p is None:
            raise UserError(f"{rel}: {why}")
        return p


def build_mesh(root: Path, name: str, spec: dict, deps: dict[str, Path] | None = None) -> MeshData:
    """The mesh of a [meshes] entry in millimetres; MeshError (naming the file or entry) if unusable."""
    scale = ms.UNIT_SCALE_TO_MM[spec["units"]]
    if spec["primitive"]:
        m = primitive(
            spec["primitive"],
            extents=spec["extents"],
            radius=spec["radius"],
            height=spec["height"],
            resolution=spec["resolution"],
        )
        m.vertices = m.vertices * scale
        return check_mesh(m, f"meshes.{name}")
    path, why = locate(root, deps or {}, spec["path"])
    if path is None:
        raise UserError(f"meshes.{name}.path: {why}")
    m = load_file(path, scale, spec["merge_vertices"], label=spec["path"])
    if spec.get("reorder"):
        m = reorder_mesh(m)
    return m


def material_presets() -> dict[str, dict]:
    """Named ChainMail materials calibrated against FEM (`chainsim study calibrate` writes them)."""
    try:
        return tomllib.loads(PRESET_FILE.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return {}

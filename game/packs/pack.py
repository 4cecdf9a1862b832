"""Asset packs: discovery, manifest parsing and validation, and the loaded `Pack`.

A pack is a folder with `pack.toml`, meshes and docs. Packs are data only: nothing in a pack is
ever imported or executed. They are found, in this order of precedence:

    1. folders given with --pack-path DIR (a pack folder, or a folder of pack folders)
    2. folders in the CHAINSIM_PACK_PATH environment variable (os.pathsep separated)
    3. packs installed with pip, through the `chainsim.packs` entry-point group (each entry point's
       value names a package; the pack is the package's folder, read as data)
    4. the built-in packs in `assets/`

Validation collects every problem at once, each as `file:line: key.path: what is wrong`.
"""

from __future__ import annotations

import difflib
import os
import re
import tomllib
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from importlib.util import find_spec
from pathlib import Path
from typing import Any

from chainsim.assets import ASSETS_DIR
from chainsim.components.registry import (
    COMPONENTS,
    SECTION_STYLE,
    SECTIONS,
    FieldError,
    Schema,
    convert,
    default_value,
    load_all,
)
from chainsim.engine.errors import UserError
from chainsim.engine.meshes import MeshData, MeshError, load_file, max_mesh_bytes, primitive
from chainsim.engine.reorder import reorder_mesh
from chainsim.game.packs import schema as ms
from chainsim.systems.procedures import PROCEDURES

BUILTIN_DIR = ASSETS_DIR
ENV_PATH = "CHAINSIM_PACK_PATH"
ENTRY_POINT_GROUP = "chainsim.packs"
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]*$")


# -- problems ----------------------------------------------------------------------------------


@dataclass(slots=True)
class Problem:
    file: str
    key: str
    message: str
    line: int | None = None

    def __str__(self) -> str:
        loc = f"{self.file}:{self.line}" if self.line else self.file
        return f"{loc}: {self.key}: {self.message}" if self.key else f"{loc}: {self.message}"


class PackError(UserError):
    """A pack that failed validation; `problems` lists them all."""

    def __init__(self, problems: list[Problem]):
        self.problems = problems
        super().__init__("\n".join(str(p) for p in problems))


def _line_of(text: str, keypath: str) -> int | None:
    """Best-effort line number of a dotted key in TOML text (tables, arrays of tables, inline keys)."""
    parts = keypath.split(".")
    lines = text.splitlines()
    header: list[str] = []
    best = None
    for i, raw in enumerate(lines, 1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        m = re.match(r"^\[\[?\s*([^\]]+?)\s*\]\]?", s)
        if m:
            header = [p.strip().strip('"') for p in m.group(1).split(".")]
            if header == parts:
                return i
            if header[: len(parts)] == parts and best is None:
                best = i  # the first sub-table of the section in question
            continue
        m = re.match(r'^("?[A-Za-z0-9_\-]+"?)\s*=', s)
        if m:
            key = m.group(1).strip('"')
            full = header + [key]
            # arrays of tables have a numeric index in keypath: drop indices when comparing
            kp = [p for p in parts if not p.isdigit()]
            if full == kp:
                return i
            if kp[: len(full)] == full and best is None:
                best = i  # a nested inline table holds the key
    return best


# -- discovery ---------------------------------------------------------------------------------


@dataclass(slots=True)
class Found:
    name: str
    path: Path
    source: str  # "builtin", "pack-path", "env", "installed"


def _scan(folder: Path, source: str) -> list[Found]:
    out = []
    if (folder / "pack.toml").is_file():
        return [Found(_pack_name(folder), folder, source)]
    if folder.is_dir():
        for sub in sorted(folder.iterdir()):
            if (sub / "pack.toml").is_file():
                out.append(Found(_pack_name(sub), sub, source))
    return out


def _pack_name(folder: Path) -> str:
    try:
        data = tomllib.loads((folder / "pack.toml").read_text(encoding="utf-8"))
        name = data.get("pack", {}).get("name")
        if isinstance(name, str) and name:
            return name
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError, AttributeError):
        pass
    return folder.name


def _installed() -> list[Found]:

    out = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        try:
            spec = find_spec(ep.value)  # locates the package folder without executing it
        except (ImportError, ValueError):
            continue
        if spec and spec.submodule_search_locations:
            for loc in spec.submodule_search_locations:
                out.extend(_scan(Path(loc), "installed"))
    return out


def discover(pack_paths: list[str] | tuple = ()) -> list[Found]:
    """All packs found, highest precedence first; a later pack with the same name is shadowed."""
    found: list[Found] = []
    for p in pack_paths:
        path = Path(p)
        if not path.is_dir():
            raise UserError(f"--pack-path {p}: not a folder")
        found.extend(_scan(path, "pack-path"))
    for p in filter(None, os.environ.get(ENV_PATH, "").split(os.pathsep)):
        found.extend(_scan(Path(p), "env"))
    found.extend(_installed())
    found.extend(_scan(BUILTIN_DIR, "builtin"))
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
    seen = {}
    for f in discover(pack_paths):
        seen.setdefault(f.name, f)
    if name in seen:
        return seen[name].path, (scene or None)
    known = ", ".join(sorted(seen)) or "none"
    raise UserError(f"pack '{name}' not found; known packs: {known} (add folders with --pack-path or {ENV_PATH})")


# -- parsing and validation --------------------------------------------------------------------


def _inside(root: Path, rel: str) -> Path | None:
    """The resolved path of `rel` if it stays inside `root` (symlinks followed), else None."""
    if os.path.isabs(rel):
        return None
    target = (root / rel).resolve()
    try:
        target.relative_to(root.resolve())
    except ValueError:
        return None
    return target


@dataclass
class Pack:
    """A validated pack: converted manifest sections and lazily loaded meshes."""

    root: Path
    manifest: dict[str, Any]
    texts: dict[str, str] = field(default_factory=dict)
    _meshes: dict[str, MeshData] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.manifest["pack"]["name"]

    def section(self, name: str) -> Any:
        return self.manifest.get(name, {} if SECTION_STYLE[name] != "list" else [])

    def mesh(self, name: str) -> MeshData:
        if name not in self._meshes:
            self._meshes[name] = build_mesh(self.root, name, self.manifest["meshes"][name])
        return self._meshes[name]

    def scene_names(self) -> list[str]:
        return list(self.section("scenes"))

    def scene(self, name: str | None) -> tuple[str, dict]:
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
        return _inside(self.root, self.section("docs")[name]["path"]).read_text(encoding="utf-8")

    def file(self, rel: str) -> Path:
        p = _inside(self.root, rel)
        if p is None:
            raise UserError(f"{rel}: path escapes the pack folder {self.root}")
        return p


def build_mesh(root: Path, name: str, spec: dict) -> MeshData:
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
        return m
    path = _inside(root, spec["path"])
    m = load_file(path, scale, spec["merge_vertices"], label=spec["path"])
    if spec.get("reorder"):
        m = reorder_mesh(m)
    return m


class _Validator:
    def __init__(self, root: Path):
        self.root = root
        self.problems: list[Problem] = []
        self.texts: dict[str, str] = {}

    def add(self, file: str, key: str, msg: str) -> None:
        line = _line_of(self.texts.get(file, ""), key) if key else None
        self.problems.append(Problem(file, key, msg, line))

    def read_toml(self, rel: str) -> dict | None:
        path = _inside(self.root, rel)
        if path is None:
            self.add("pack.toml", "pack.includes", f"'{rel}' escapes the pack folder")
            return None
        try:
            text = path.read_text(encoding="utf-8")
        except FileNotFoundError:
            self.problems.append(Problem(rel, "", "file not found"))
            return None
        except (OSError, UnicodeDecodeError) as e:
            self.problems.append(Problem(rel, "", f"cannot read ({getattr(e, 'strerror', None) or e})"))
            return None
        self.texts[rel] = text
        try:
            return tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            msg = str(e)
            m = re.search(r"\(at line (\d+), column (\d+)\)", msg)
            line = int(m.group(1)) if m else None
            detail = re.sub(r" \(at line.*", "", msg)
            self.problems.append(Problem(rel, "", f"TOML syntax error: {detail}", line))
            return None

    def table(self, file: str, key: str, raw: Any, schema: Schema) -> dict | None:
        """Check one table against a schema; returns converted values with defaults filled in."""
        if not isinstance(raw, dict):
            self.add(file, key, f"expected a table, got {type(raw).__name__}")
            return None
        out: dict[str, Any] = {}
        names = [f.name for f in schema.fields]
        for k, v in raw.items():
            f = schema.field(k)
            if f is None:
                if schema.open_keys:
                    out[k] = v
                    continue
                hint = difflib.get_close_matches(k, names, n=1)
                extra = f" (did you mean '{hint[0]}'?)" if hint else f"; known keys: {', '.join(names)}"
                self.add(file, f"{key}.{k}", f"unknown key{extra}")
                continue
            try:
                out[k] = convert(f, v)
            except FieldError as e:
                self.add(file, f"{key}.{k}", str(e))
                continue
            if f.kind == "table_list" and f.item is not None:
                out[k] = [self.table(file, f"{key}.{k}.{i}", item, f.item) or {} for i, item in enumerate(v)]
        for f in schema.fields:
            if f.name not in raw:
                if f.required:
                    self.add(file, key, f"missing required key '{f.name}' ({f.help})")
                else:
                    out[f.name] = default_value(f)
        return out


def _merge(into: dict, other: dict, v: _Validator, file: str) -> None:
    for sec, val in other.items():
        if sec == "pack":
            v.add(file, "pack", "an included file cannot redefine [pack]")
            continue
        if sec in into and isinstance(into[sec], dict) and isinstance(val, dict):
            for k, item in val.items():
                if k in into[sec]:
                    v.add(file, f"{sec}.{k}", "already defined in another manifest file")
                else:
                    into[sec][k] = item
        elif sec in into and isinstance(into[sec], list) and isinstance(val, list):
            into[sec].extend(val)
        elif sec in into:
            v.add(file, sec, "conflicts with the same section elsewhere")
        else:
            into[sec] = val


def validate(root: Path, *, load_meshes: bool = True) -> tuple[Pack | None, list[Problem]]:
    """Validate a pack folder; returns (pack or None, every problem found)."""
    load_all()
    root = Path(root)
    v = _Validator(root)
    if not root.is_dir():
        return None, [Problem(str(root), "", "not a folder")]
    raw = v.read_toml("pack.toml")
    if raw is None:
        return None, v.problems
    F = "pack.toml"
    if "pack" not in raw:
        v.add(F, "", "missing the [pack] table (name and format)")
    incs = raw.get("pack", {}).get("includes", []) if isinstance(raw.get("pack"), dict) else []
    if isinstance(incs, list):
        for inc in incs:
            if isinstance(inc, str):
                sub = v.read_toml(inc)
                if sub is not None:
                    _merge(raw, sub, v, inc)
    origin: dict[str, str] = {}  # section.key -> file for messages
    for rel, text in v.texts.items():
        for sec in SECTION_STYLE:
            for m in re.finditer(rf"^\[{sec}\.([A-Za-z0-9_\-]+)", text, re.M):
                origin.setdefault(f"{sec}.{m.group(1)}", rel)

    def file_of(key: str) -> str:
        parts = key.split(".")
        return origin.get(".".join(parts[:2]), F)

    man: dict[str, Any] = {}
    for sec, val in raw.items():
        if sec == "entities":
            continue
        if sec not in SECTIONS:
            hint = difflib.get_close_matches(sec, list(SECTIONS) + ["entities"], n=1)
            v.add(
                F,
                sec,
                "unknown section"
                + (
                    f" (did you mean '{hint[0]}'?)"
                    if hint
                    else f"; sections: {', '.join(list(SECTIONS) + ['entities'])}"
                ),
            )
            continue
        style = SECTION_STYLE[sec]
        schema = SECTIONS[sec]
        if style == "table":
            man[sec] = v.table(F, sec, val, schema) or {}
        elif style == "named":
            if not isinstance(val, dict):
                v.add(F, sec, f"expected named tables [{sec}.NAME]")
                continue
            man[sec] = {}
            for name, item in val.items():
                key = f"{sec}.{name}"
                conv = v.table(file_of(key), key, item, schema)
                if conv is not None:
                    if sec == "materials" and conv.get("preset"):
                        _apply_preset(v, file_of(key), key, conv, item)
                    man[sec][name] = conv
        else:
            if not isinstance(val, list):
                v.add(F, sec, f"expected an array of tables [[{sec}]]")
                continue
            man[sec] = [v.table(F, f"{sec}.{i}", item, schema) or {} for i, item in enumerate(val)]
    for sec, style in SECTION_STYLE.items():
        if sec not in man and sec not in ("pack",):
            man[sec] = v.table(F, sec, {}, SECTIONS[sec]) if style == "table" else ([] if style == "list" else {})
    pk = man.get("pack") or {}
    if pk:
        if "name" in pk and not NAME_RE.match(pk["name"]):
            v.add(
                F,
                "pack.name",
                f"'{pk['name']}' is not a valid pack name (letters, digits, - and _; no spaces or slashes)",
            )
        if "format" in pk and pk["format"] != ms.FORMAT_VERSION:
            v.add(
                F,
                "pack.format",
                f"format {pk['format']} is not supported; this chainsim reads format {ms.FORMAT_VERSION}",
            )
        if pk.get("attribution"):
            _check_path(v, root, F, "pack.attribution", pk["attribution"])
        if pk.get("procedure"):
            if pk["procedure"] not in PROCEDURES:
                v.add(
                    F,
                    "pack.procedure",
                    f"unknown procedure '{pk['procedure']}'; built-in procedures: {', '.join(sorted(PROCEDURES))}",
                )
    # meshes
    for name, spec in man.get("meshes", {}).items():
        key = f"meshes.{name}"
        if any(p.key == key or p.key.startswith(key + ".") for p in v.problems):
            continue  # its table is already wrong; checking the file would only repeat that
        has_path, has_prim = bool(spec.get("path")), bool(spec.get("primitive"))
        if has_path == has_prim:
            v.add(file_of(key), key, "give exactly one of 'path' or 'primitive'")
            continue
        if has_path:
            p = _check_path(v, root, file_of(key), f"{key}.path", spec["path"])
            if p is None:
                continue
            if p.stat().st_size > max_mesh_bytes():
                v.add(
                    file_of(key),
                    f"{key}.path",
                    f"{spec['path']} is {p.stat().st_size / 1048576:.2f} MB, over the {max_mesh_bytes() / 1048576:.3g} MB mesh limit (CHAINSIM_MAX_MESH_MB)",
                )
                continue
        if load_meshes:
            try:
                build_mesh(root, name, spec)
            except MeshError as e:
                v.add(file_of(key), f"{key}.path" if has_path else key, str(e))
    # docs
    for name, spec in man.get("docs", {}).items():
        if "path" in spec:
            _check_path(v, root, file_of(f"docs.{name}"), f"docs.{name}.path", spec["path"])
    for name, spec in man.get("scenes", {}).items():
        if spec.get("script"):
            _check_path(v, root, F, f"scenes.{name}.script", spec["script"])
    # entities
    ents_raw = raw.get("entities", {})
    entities: dict[str, dict[str, Any]] = {}
    if not isinstance(ents_raw, dict):
        v.add(F, "entities", "expected named tables [entities.NAME]")
        ents_raw = {}
    for ename, comps in ents_raw.items():
        key = f"entities.{ename}"
        if not isinstance(comps, dict):
            v.add(F, key, "expected a table of components")
            continue
        entities[ename] = {}
        for cname, ctable in comps.items():
            schema = COMPONENTS.get(cname)
            if schema is None:
                hint = difflib.get_close_matches(cname, list(COMPONENTS), n=1)
                v.add(
                    file_of(key),
                    f"{key}.{cname}",
                    "unknown component"
                    + (f" (did you mean '{hint[0]}'?)" if hint else f"; components: {', '.join(sorted(COMPONENTS))}"),
                )
                continue
            conv = v.table(file_of(key), f"{key}.{cname}", ctable, schema)
            if conv is not None:
                entities[ename][cname] = conv
                for f in schema.fields:
                    ref = conv.get(f.name)
                    if f.kind == "mesh" and ref and ref not in man.get("meshes", {}):
                        v.add(file_of(key), f"{key}.{cname}.{f.name}", f"no mesh named '{ref}' in [meshes]")
                    if f.kind == "material" and ref and ref not in man.get("materials", {}):
                        v.add(file_of(key), f"{key}.{cname}.{f.name}", f"no material named '{ref}' in [materials]")
    man["entities"] = entities
    for ename, comps in entities.items():
        for cname, conv in comps.items():
            for f in COMPONENTS[cname].fields:
                if f.kind == "entity" and conv.get(f.name) and conv[f.name] not in entities:
                    v.add(F, f"entities.{ename}.{cname}.{f.name}", f"no entity named '{conv[f.name]}'")
    # cross references
    for sname, sc in man.get("scenes", {}).items():
        for e in sc.get("entities", []):
            if e not in entities:
                v.add(F, f"scenes.{sname}.entities", f"no entity named '{e}'")
        if sc.get("layout") and sc["layout"] not in man.get("layouts", {}):
            v.add(F, f"scenes.{sname}.layout", f"no layout named '{sc['layout']}'")
    for lname, lay in man.get("layouts", {}).items():
        names = [vp.get("name") for vp in lay.get("viewports", [])]
        for i, vp in enumerate(lay.get("viewports", [])):
            if names.count(vp.get("name")) > 1:
                v.add(F, f"layouts.{lname}.viewports.{i}.name", f"duplicate viewport name '{vp.get('name')}'")
            if vp.get("kind") == "attached" and not vp.get("attach"):
                v.add(F, f"layouts.{lname}.viewports.{i}", "an attached viewport needs 'attach' (an entity name)")
            if vp.get("attach") and vp["attach"] not in entities:
                v.add(F, f"layouts.{lname}.viewports.{i}.attach", f"no entity named '{vp['attach']}'")
            if "far" in vp and "near" in vp and vp["far"] <= vp["near"]:
                v.add(F, f"layouts.{lname}.viewports.{i}.far", "must be greater than 'near'")
        panels = [vp.get("name") for vp in lay.get("viewports", []) if vp.get("kind") == "panel"]
        for i, w in enumerate(lay.get("widgets", [])):
            if w.get("viewport") and w["viewport"] not in panels:
                v.add(
                    F,
                    f"layouts.{lname}.widgets.{i}.viewport",
                    f"'{w['viewport']}' is not a panel viewport of this layout (panels: {', '.join(panels) or 'none'})",
                )
            if lay.get("widgets") and not panels:
                v.add(F, f"layouts.{lname}.widgets", "widgets need a viewport of kind 'panel'")
                break
    for i, st in enumerate(man.get("steps", [])):
        if st.get("docs") and st["docs"] not in man.get("docs", {}):
            v.add(F, f"steps.{i}.docs", f"no docs page named '{st['docs']}'")
    ids = [st.get("id") for st in man.get("steps", [])]
    for i, sid in enumerate(ids):
        if sid is not None and ids.count(sid) > 1:
            v.add(F, f"steps.{i}.id", f"duplicate step id '{sid}'")
            break
    if v.problems:
        return None, v.problems
    return Pack(root=root, manifest=man, texts=v.texts), []


PRESET_FILE = BUILTIN_DIR / "presets" / "materials.toml"
PRESET_KEYS = {"alpha_min": "alpha_min", "alpha_max": "alpha_max", "beta": "beta", "relax": "relax_iterations"}


def material_presets() -> dict[str, dict]:
    """Named ChainMail materials calibrated against FEM (`chainsim study calibrate` writes them)."""
    try:
        return tomllib.loads(PRESET_FILE.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return {}


def _apply_preset(v: _Validator, file: str, key: str, conv: dict, raw: dict) -> None:
    """Fill the ChainMail keys the material does not set itself from its named preset."""
    presets = material_presets()
    preset = presets.get(conv["preset"])
    if preset is None:
        v.add(
            file, f"{key}.preset", f"unknown preset '{conv['preset']}'; presets: {', '.join(sorted(presets)) or 'none'}"
        )
        return
    for mkey, pkey in PRESET_KEYS.items():
        if mkey not in raw and pkey in preset:
            conv[mkey] = int(preset[pkey]) if mkey == "relax" else float(preset[pkey])


def _check_path(v: _Validator, root: Path, file: str, key: str, rel: str) -> Path | None:
    p = _inside(root, rel)
    if p is None:
        v.add(file, key, f"'{rel}' escapes the pack folder (paths must stay inside {root.name}/)")
        return None
    if not p.exists():
        v.add(file, key, f"file '{rel}' not found")
        return None
    if not p.is_file() or not os.access(p, os.R_OK):
        v.add(file, key, f"'{rel}' is not a readable file")
        return None
    return p


def load(root: Path) -> Pack:
    """Validate and return the pack, or raise PackError listing every problem."""
    pack, problems = validate(root, load_meshes=False)
    if problems:
        raise PackError(problems)
    return pack

"""Validation of a pack manifest: one small check per part, every problem collected at once.

`Validator` reads the manifest files (chainsim.systems.engine.datafile: size, nesting and number limits)
and checks tables against their schemas (chainsim.components.registry: every value bounded); the
`check_*` functions each own one part of the manifest and are run in order by
`chainsim.game.packs.pack.validate`. Problems read `file:line: key.path: what is wrong`, one line
each; `problem_at` places a message about a validated pack (from starting its scenes, which the app
does: chainsim.game.trainer.headless.validate_pack) the same way.
"""

from __future__ import annotations

import difflib
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from chainsim.components.registry import (
    COMPONENTS,
    SECTION_STYLE,
    SECTIONS,
    FieldError,
    Schema,
    convert,
    default_value,
)
from chainsim.game.packs import declarations as ms
from chainsim.game.packs.discovery import MANIFEST, NAME_RE
from chainsim.game.packs.model import PRESET_KEYS, Pack, build_mesh, locate, material_presets
from chainsim.game.packs.requires import resolve_requires
from chainsim.game.records import validate as records
from chainsim.systems.engine import datafile, limits
from chainsim.systems.engine.errors import UserError, printable
from chainsim.systems.engine.meshes import MeshData, MeshError, check_primitive, max_mesh_bytes
from chainsim.systems.procedures import PROCEDURES

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


# -- problems ----------------------------------------------------------------------------------


@dataclass(slots=True)
class Problem:
    file: str
    key: str
    message: str
    line: int | None = None

    def __str__(self) -> str:  # one line: keys and messages may quote anything the manifest holds
        loc = printable(f"{self.file}:{self.line}" if self.line else self.file)
        key, message = printable(self.key), printable(self.message)
        return f"{loc}: {key}: {message}" if key else f"{loc}: {message}"


class PackError(UserError):
    """A pack that failed validation; `problems` lists them all."""

    def __init__(self, problems: list[Problem]):
        self.problems = problems
        super().__init__("\n".join(str(p) for p in problems))

    def lines(self) -> list[str]:
        return [str(p) for p in self.problems]


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


class Validator:
    """Collects problems while the per-section checks below walk one pack."""

    def __init__(self, root: Path, pack_paths=()):
        self.root = root
        self.pack_paths = tuple(pack_paths)
        self.deps: dict[str, Path] = {}  # required pack name -> folder (read_manifest fills it)
        self.problems: list[Problem] = []
        self.texts: dict[str, str] = {}
        self.origin: dict[str, str] = {}  # "section.name" -> the manifest file that defines it

    def add(self, file: str, key: str, msg: str) -> None:
        line = _line_of(self.texts.get(file, ""), key) if key else None
        self.problems.append(Problem(file, key, msg, line))

    def file_of(self, key: str) -> str:
        return self.origin.get(".".join(key.split(".")[:2]), MANIFEST)

    def has_problem(self, key: str) -> bool:
        return any(p.key == key or p.key.startswith(key + ".") for p in self.problems)

    def read_toml(self, rel: str) -> dict | None:
        path, why = locate(self.root, self.deps, rel)
        if path is None:
            self.add(MANIFEST, "pack.includes", why)
            return None
        try:
            text = datafile.read_text(path, max_bytes=limits.MAX_MANIFEST_BYTES, what="manifest file")
        except datafile.DataError as e:
            if rel == MANIFEST:
                self.problems.append(Problem(rel, "", e.detail, e.line))
            else:  # an included file that is missing or unreadable: the key that names it is what to fix
                self.add(MANIFEST, "pack.includes", f"'{rel}': {e.detail}")
            return None
        self.texts[rel] = text
        try:
            return datafile.parse_toml(text, rel)
        except datafile.DataError as e:
            line = e.line or (_line_of(text, e.key) if e.key else None)
            self.problems.append(Problem(rel, e.key, e.detail, line))
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

    def path(self, file: str, key: str, rel: str) -> Path | None:
        """The file a pack path names, if it stays inside the pack (or the required pack it names) and is
        a readable file."""
        p, why = locate(self.root, self.deps, rel)
        if p is None:
            self.add(file, key, why)
            return None
        if not p.exists():
            self.add(file, key, f"file '{rel}' not found")
            return None
        if not p.is_file() or not os.access(p, os.R_OK):
            self.add(file, key, f"'{rel}' is not a readable file")
            return None
        return p


def _merge(into: dict, other: dict, v: Validator, file: str) -> None:
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


# -- the checks, one per part of the manifest -------------------------------------------------------
#
# `validate` runs them in order; each adds Problems and returns what later checks need. The last,
# `check_start`, starts every scene the way `run` does (without stepping), so whatever `run` would
# refuse at start `validate` has already reported.


def read_manifest(v: Validator) -> dict | None:
    """pack.toml with its includes merged in; records which file defines each named table."""
    raw = v.read_toml(MANIFEST)
    if raw is None:
        return None
    if "pack" not in raw:
        v.add(MANIFEST, "pack", "missing the [pack] table (name and format)")
    _requires(v, raw)  # before the includes, which may name files of a required pack
    incs = raw.get("pack", {}).get("includes", []) if isinstance(raw.get("pack"), dict) else []
    if isinstance(incs, list):
        for inc in incs:
            if isinstance(inc, str) and _CONTROL.search(inc):
                v.add(MANIFEST, "pack.includes", f"path {inc[:60]!r} contains a control character")
            elif isinstance(inc, str):
                sub = v.read_toml(inc)
                if sub is not None:
                    _merge(raw, sub, v, inc)
    for rel, text in v.texts.items():
        for sec in SECTION_STYLE:
            for m in re.finditer(rf"^\[{sec}\.([A-Za-z0-9_\-]+)", text, re.M):
                v.origin.setdefault(f"{sec}.{m.group(1)}", rel)
    return raw


def _requires(v: Validator, raw: dict) -> None:
    """[pack] requires: every required pack found, none missing further down the chain, no cycle.
    A value of the wrong type is left to the [pack] schema check, which reports it."""
    pk = raw.get("pack")
    if not isinstance(pk, dict):
        return
    req = pk.get("requires", [])
    if not isinstance(req, list) or not all(isinstance(r, str) for r in req):
        return
    name = pk.get("name")
    name = name if isinstance(name, str) else ""
    v.deps, problems = resolve_requires(v.root, name, req, v.pack_paths)
    for msg in problems:
        v.add(MANIFEST, "pack.requires", msg)


def check_name(v: Validator, key: str, name: str) -> bool:
    """A table name (mesh, material, entity, scene ...) within the length limit, without control characters."""
    if len(name) > limits.MAX_KEY_LENGTH:
        v.add(v.file_of(key), key, f"a name of {len(name)} characters is over the {limits.MAX_KEY_LENGTH} limit")
        return False
    if _CONTROL.search(name):
        v.add(v.file_of(key), key, f"name {name[:40]!r} contains a control character")
        return False
    return True


def check_sections(v: Validator, raw: dict) -> dict[str, Any]:
    """Every section against its schema; returns the converted manifest (entities not yet)."""
    man: dict[str, Any] = {}
    known = list(SECTIONS) + ["entities"]
    for sec, val in raw.items():
        if sec == "entities":
            continue
        if sec not in SECTIONS:
            hint = difflib.get_close_matches(sec, known, n=1)
            v.add(
                MANIFEST,
                sec,
                "unknown section" + (f" (did you mean '{hint[0]}'?)" if hint else f"; sections: {', '.join(known)}"),
            )
            continue
        style, schema = SECTION_STYLE[sec], SECTIONS[sec]
        if style == "table":
            man[sec] = v.table(MANIFEST, sec, val, schema) or {}
        elif style == "named":
            if not isinstance(val, dict):
                v.add(MANIFEST, sec, f"expected named tables [{sec}.NAME]")
                continue
            man[sec] = {}
            for name, item in val.items():
                key = f"{sec}.{name}"
                if not check_name(v, key, name):
                    continue
                conv = v.table(v.file_of(key), key, item, schema)
                if conv is not None:
                    if sec == "materials" and conv.get("preset"):
                        _apply_preset(v, v.file_of(key), key, conv, item)
                    man[sec][name] = conv
        else:
            if not isinstance(val, list):
                v.add(MANIFEST, sec, f"expected an array of tables [[{sec}]]")
                continue
            man[sec] = [v.table(MANIFEST, f"{sec}.{i}", item, schema) or {} for i, item in enumerate(val)]
    for sec, style in SECTION_STYLE.items():
        if sec not in man and sec != "pack":
            man[sec] = (
                v.table(MANIFEST, sec, {}, SECTIONS[sec]) if style == "table" else ([] if style == "list" else {})
            )
    return man


def check_pack_table(v: Validator, man: dict) -> None:
    """[pack]: name, format version, attribution file, procedure."""
    pk = man.get("pack") or {}
    if not pk:
        return
    if "name" in pk and not NAME_RE.match(pk["name"]):
        v.add(
            MANIFEST,
            "pack.name",
            f"'{pk['name'][:60]}' is not a valid pack name (letters, digits, - and _; no spaces or slashes)",
        )
    elif "name" in pk and len(pk["name"]) > limits.MAX_KEY_LENGTH:
        v.add(
            MANIFEST, "pack.name", f"a name of {len(pk['name'])} characters is over the {limits.MAX_KEY_LENGTH} limit"
        )
    if "format" in pk and pk["format"] != ms.FORMAT_VERSION:
        v.add(
            MANIFEST,
            "pack.format",
            f"format {pk['format']} is not supported; this chainsim reads format {ms.FORMAT_VERSION}",
        )
    if pk.get("attribution"):
        v.path(MANIFEST, "pack.attribution", pk["attribution"])
    if pk.get("procedure") and pk["procedure"] not in PROCEDURES:
        v.add(
            MANIFEST,
            "pack.procedure",
            f"unknown procedure '{pk['procedure']}'; built-in procedures: {', '.join(sorted(PROCEDURES))}",
        )


def check_meshes(v: Validator, man: dict, load_meshes: bool) -> dict[str, MeshData]:
    """[meshes]: one of path or primitive, size and declared counts within the limits, and (optionally) loaded.

    Returns the meshes loaded, so a validated pack does not read its files twice.
    """
    built: dict[str, MeshData] = {}
    for name, spec in man.get("meshes", {}).items():
        key = f"meshes.{name}"
        file = v.file_of(key)
        if v.has_problem(key):
            continue  # its table is already wrong; checking the file would only repeat that
        if spec.get("inside") and spec["inside"] not in man.get("meshes", {}):
            v.add(file, f"{key}.inside", f"no mesh named '{spec['inside']}' in [meshes]")
        has_path, has_prim = bool(spec.get("path")), bool(spec.get("primitive"))
        if has_path == has_prim:
            v.add(file, key, "give exactly one of 'path' or 'primitive'")
            continue
        if has_prim:
            try:
                check_primitive(spec["primitive"], spec["resolution"], key)
            except MeshError as e:
                v.add(file, f"{key}.resolution", str(e).removeprefix(f"{key}: "))
                continue
        else:
            p = v.path(file, f"{key}.path", spec["path"])
            if p is None:
                continue
            if spec.get("display") and v.path(file, f"{key}.display", spec["display"]) is None:
                continue
            limit = max_mesh_bytes()
            if p.stat().st_size > limit:
                v.add(
                    file,
                    f"{key}.path",
                    f"{spec['path']} is {p.stat().st_size / 1048576:.2f} MB, over the {limit / 1048576:.3g} MB "
                    "mesh limit (CHAINSIM_MAX_MESH_MB)",
                )
                continue
        if load_meshes:
            try:
                built[name] = build_mesh(v.root, name, spec, v.deps)
            except MeshError as e:
                v.add(file, f"{key}.path" if has_path else key, str(e))
    return built


def check_files(v: Validator, man: dict) -> None:
    """[docs] pages and scene scripts: files inside the pack."""
    for name, spec in man.get("docs", {}).items():
        if "path" in spec:
            v.path(v.file_of(f"docs.{name}"), f"docs.{name}.path", spec["path"])
    for name, spec in man.get("scenes", {}).items():
        if spec.get("script"):
            v.path(MANIFEST, f"scenes.{name}.script", spec["script"])


def check_entities(v: Validator, raw: dict, man: dict) -> dict[str, dict[str, Any]]:
    """[entities.NAME.COMPONENT]: known components, each table against its schema, mesh/material names."""
    ents_raw = raw.get("entities", {})
    entities: dict[str, dict[str, Any]] = {}
    if not isinstance(ents_raw, dict):
        v.add(MANIFEST, "entities", "expected named tables [entities.NAME]")
        return entities
    for ename, comps in ents_raw.items():
        key = f"entities.{ename}"
        if not check_name(v, key, ename):
            continue
        if not isinstance(comps, dict):
            v.add(MANIFEST, key, "expected a table of components")
            continue
        file = v.file_of(key)
        entities[ename] = {}
        for cname, ctable in comps.items():
            schema = COMPONENTS.get(cname)
            if schema is None:
                hint = difflib.get_close_matches(cname, list(COMPONENTS), n=1)
                v.add(
                    file,
                    f"{key}.{cname}",
                    "unknown component"
                    + (f" (did you mean '{hint[0]}'?)" if hint else f"; components: {', '.join(sorted(COMPONENTS))}"),
                )
                continue
            conv = v.table(file, f"{key}.{cname}", ctable, schema)
            if conv is None:
                continue
            entities[ename][cname] = conv
            for f in schema.fields:
                ref = conv.get(f.name)
                # an empty name written in the table names no mesh either (left out, a field keeps its default)
                if f.kind == "mesh" and (ref or f.name in ctable) and ref not in man.get("meshes", {}):
                    v.add(file, f"{key}.{cname}.{f.name}", f"no mesh named '{ref}' in [meshes]")
                if f.kind == "material" and ref and ref not in man.get("materials", {}):
                    v.add(file, f"{key}.{cname}.{f.name}", f"no material named '{ref}' in [materials]")
    for ename, comps in entities.items():
        for cname, conv in comps.items():
            for f in COMPONENTS[cname].fields:
                if f.kind == "entity" and conv.get(f.name) and conv[f.name] not in entities:
                    v.add(MANIFEST, f"entities.{ename}.{cname}.{f.name}", f"no entity named '{conv[f.name]}'")
    return entities


def check_scenes(v: Validator, man: dict) -> None:
    """[scenes]: entities and layout exist, and so does [pack] default_scene (the scene a run without
    PACK/SCENE starts)."""
    default = (man.get("pack") or {}).get("default_scene")
    if default and man.get("scenes") and default not in man["scenes"]:
        v.add(MANIFEST, "pack.default_scene", f"no scene named '{default}' (scenes: {', '.join(man['scenes'])})")
    for sname, sc in man.get("scenes", {}).items():
        for e in sc.get("entities", []):
            if e not in man["entities"]:
                v.add(MANIFEST, f"scenes.{sname}.entities", f"no entity named '{e}'")
        if sc.get("layout") and sc["layout"] not in man.get("layouts", {}):
            v.add(MANIFEST, f"scenes.{sname}.layout", f"no layout named '{sc['layout']}'")


def check_layouts(v: Validator, man: dict) -> None:
    """[layouts]: unique viewport names, attached viewports on entities, clip planes, widget panels."""
    for lname, lay in man.get("layouts", {}).items():
        key = f"layouts.{lname}"
        vps = lay.get("viewports", [])
        names = [vp.get("name") for vp in vps]
        for i, vp in enumerate(vps):
            if names.count(vp.get("name")) > 1:
                v.add(MANIFEST, f"{key}.viewports.{i}.name", f"duplicate viewport name '{vp.get('name')}'")
            if vp.get("kind") == "attached" and not vp.get("attach"):
                v.add(MANIFEST, f"{key}.viewports.{i}", "an attached viewport needs 'attach' (an entity name)")
            if vp.get("attach") and vp["attach"] not in man["entities"]:
                v.add(MANIFEST, f"{key}.viewports.{i}.attach", f"no entity named '{vp['attach']}'")
            if "far" in vp and "near" in vp and vp["far"] <= vp["near"]:
                v.add(MANIFEST, f"{key}.viewports.{i}.far", "must be greater than 'near'")
        panels = [vp["name"] for vp in vps if vp.get("kind") == "panel" and vp.get("name")]
        for i, w in enumerate(lay.get("widgets", [])):
            if w.get("viewport") and w["viewport"] not in panels:
                v.add(
                    MANIFEST,
                    f"{key}.widgets.{i}.viewport",
                    f"'{w['viewport']}' is not a panel viewport of this layout (panels: {', '.join(panels) or 'none'})",
                )
            if lay.get("widgets") and not panels:
                v.add(MANIFEST, f"{key}.widgets", "widgets need a viewport of kind 'panel'")
                break
            if w.get("min", 0.0) > w.get("max", 1.0):
                v.add(MANIFEST, f"{key}.widgets.{i}.max", "must be >= 'min'")


def check_steps(v: Validator, man: dict) -> None:
    """[[steps]]: docs pages exist, ids unique."""
    for i, st in enumerate(man.get("steps", [])):
        if st.get("docs") and st["docs"] not in man.get("docs", {}):
            v.add(MANIFEST, f"steps.{i}.docs", f"no docs page named '{st['docs']}'")
    ids = [st.get("id") for st in man.get("steps", [])]
    for i, sid in enumerate(ids):
        if sid is not None and ids.count(sid) > 1:
            v.add(MANIFEST, f"steps.{i}.id", f"duplicate step id '{sid}'")
            break


def check_procedure(v: Validator, man: dict) -> None:
    """A pack whose procedure keeps attempts in the records: what its procedure formats and refers to
    (the procedure's declared pack checks), and the limits the records store puts on the attempts it
    saves, so that no attempt the pack produces is refused when the trainee saves it. Run on an
    otherwise valid manifest only: the checks read the tables' converted values."""
    name = (man.get("pack") or {}).get("procedure")
    proc = PROCEDURES.get(name) if name else None
    if proc is None or proc.layout is None or v.problems:
        return
    for key, msg in proc.pack_problems(man) if proc.pack_problems is not None else []:
        v.add(v.file_of(key), key, msg)
    _records_limits(v, man, proc.name, proc.needs_steps)
    for key, ent in proc.stored_targets(man) if proc.stored_targets is not None else []:
        if ent in man.get("entities", {}) and not records.TARGET_RE.fullmatch(ent):
            v.add(
                v.file_of(key),
                key,
                f"'{ent[:60]}' can be touched in the {proc.name} procedure, and an attempt stores what it touched "
                "last: such entities are named in lower_snake_case (a-z, 0-9, _; up to 64)",
            )
            break


def _records_limits(v: Validator, man: dict, procedure: str, needs_steps: bool) -> None:
    # the pack's name, metric names and step ids are stored with each attempt
    name = man["pack"].get("name", "")
    if len(name) > records.NAME_MAX:
        v.add(
            MANIFEST,
            "pack.name",
            f"a {procedure} pack's name is stored with each attempt: at most {records.NAME_MAX} characters, "
            f"not {len(name)}",
        )
    metrics = man.get("metrics", {})
    if len(metrics) > records.MAX_METRICS:
        v.add(MANIFEST, "metrics", f"{len(metrics)} metrics; an attempt stores at most {records.MAX_METRICS}")
    for mname in metrics:
        if not records.METRIC_RE.fullmatch(mname):
            key = f"metrics.{mname}"
            v.add(v.file_of(key), key, "a metric's name is letters, digits and _ (up to 64), starting with a letter")
    steps = man.get("steps", [])
    if not steps and needs_steps:
        v.add(
            MANIFEST, "steps", f"the {procedure} procedure needs at least one [[steps]] (its time is booked per step)"
        )
    for i, st in enumerate(steps):
        if not records.STEP_RE.fullmatch(st.get("id", "")):
            v.add(
                MANIFEST,
                f"steps.{i}.id",
                "a step id is 1-64 letters, digits, '_', '.' or '-', starting with a "
                "letter or digit (attempts store their time per step)",
            )


#: the shell's tables a start-up message may name a key of; every named table a feature or procedure declares
#: (its anatomy, say) may be named too, as registered when the message is placed
_SHELL_TABLES = ("entities", "meshes", "materials", "scenes", "layouts", "settings", "pack")


def _key_prefix() -> re.Pattern[str]:
    tables = sorted({*_SHELL_TABLES, *(name for name, style in SECTION_STYLE.items() if style == "named")})
    return re.compile(rf"^((?:{'|'.join(map(re.escape, tables))})(?:\.[A-Za-z0-9_\-]+)+): (.*)$", re.S)


def problem_at(pack: Pack, scene: str, message: str) -> Problem:
    """A Problem for a message about a validated pack (from starting `scene`), placed at the key it names."""
    m = _key_prefix().match(message)
    key, text = (
        (m.group(1), m.group(2)) if m else (f"scenes.{scene}" if scene in pack.section("scenes") else "", message)
    )
    file = pack.origin.get(".".join(key.split(".")[:2]), MANIFEST)
    line = _line_of(pack.texts.get(file, ""), key) if key else None
    return Problem(file, key, text, line)


def _apply_preset(v: Validator, file: str, key: str, conv: dict, raw: dict) -> None:
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
            fld = SECTIONS["materials"].field(mkey)
            assert fld is not None  # PRESET_KEYS names material fields
            try:  # a presets file is data too: its values meet the same bounds as the manifest's
                conv[mkey] = convert(fld, preset[pkey])
            except FieldError as e:
                v.add(file, f"{key}.preset", f"preset '{conv['preset']}' {pkey}: {e}")

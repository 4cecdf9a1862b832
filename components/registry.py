"""The one registry of every manifest section and component type: type, default, units, help.

Validation of pack.toml, the loader that turns tables into components, and the modder reference
(`chainsim docs components`) are all driven from these declarations, so they cannot drift apart
(the SOFA habit of declaring each field once). Components declare their fields with `prop()` in
their dataclass and register with `@component("name", help=...)`; manifest sections are declared
below with `section()`.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import pkgutil
from collections.abc import Callable
from dataclasses import MISSING, dataclass
from typing import Any

import numpy as np

import chainsim.components


class _Required:
    def __repr__(self) -> str:
        return "REQUIRED"


REQUIRED = _Required()  # a field with no default must appear in the manifest

KINDS = {
    "str": "text",
    "int": "integer",
    "float": "number",
    "bool": "true or false",
    "vec2": "array of 2 numbers",
    "vec3": "array of 3 numbers",
    "vec4": "array of 4 numbers",
    "quat": "array of 4 numbers [w, x, y, z] (a rotation; normalised on load)",
    "rect": "array of 4 numbers [x, y, width, height] in window fractions 0..1",
    "str_list": "array of text",
    "int_list": "array of integers",
    "float_list": "array of numbers",
    "enum": "one of the listed words",
    "path": "file path relative to the pack folder",
    "mesh": "name of a [meshes] entry",
    "material": "name of a [materials] entry",
    "entity": "name of an entity",
    "table_list": "array of tables",
    "any": "number, text or true/false",
}


@dataclass(frozen=True, slots=True)
class Field:
    name: str
    kind: str
    default: Any = REQUIRED
    units: str = ""
    help: str = ""
    choices: tuple = ()
    min: float | None = None
    max: float | None = None
    item: Schema | None = None  # schema of each table in a table_list

    @property
    def required(self) -> bool:
        return self.default is REQUIRED


@dataclass(frozen=True, slots=True)
class Schema:
    """A table's fields: a manifest section entry or a component."""

    name: str
    help: str
    fields: tuple[Field, ...]
    cls: type | None = None  # component class, for component schemas
    build: Callable | None = None  # component hook run at spawn: build(component, ctx)
    open_keys: bool = False  # free-form keys allowed (settings)

    def field(self, key: str) -> Field | None:
        for f in self.fields:
            if f.name == key:
                return f
        return None


def prop(
    kind: str,
    default: Any = REQUIRED,
    *,
    units: str = "",
    help: str = "",
    choices: tuple = (),
    min: float | None = None,
    max: float | None = None,
):
    """A dataclass field that is also a manifest key (see module docstring)."""
    if kind not in KINDS:
        raise ValueError(f"unknown field kind {kind!r}")
    meta = {"chainsim": dict(kind=kind, units=units, help=help, choices=tuple(choices), min=min, max=max)}
    if default is REQUIRED:
        return dataclasses.field(metadata=meta)
    if isinstance(default, (list, dict, set, np.ndarray, tuple)) and not isinstance(default, str):
        frozen = default
        return dataclasses.field(default_factory=lambda: _copy_default(frozen), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _copy_default(v):
    if isinstance(v, np.ndarray):
        return v.copy()
    if isinstance(v, tuple):
        return np.array(v, dtype=np.float64)
    return type(v)(v)


COMPONENTS: dict[str, Schema] = {}
SECTIONS: dict[str, Schema] = {}
SECTION_STYLE: dict[str, str] = {}  # "table" (one table), "named" (table of named tables), "list" (array of tables)


def component(name: str, *, help: str, build: Callable | None = None):
    """Register a component dataclass under a manifest name (`[entities.X.<name>]`)."""

    def deco(cls):
        fields = []
        for f in dataclasses.fields(cls):
            meta = f.metadata.get("chainsim")
            if meta is None:
                continue  # runtime state, not a manifest key
            if f.default is not MISSING:
                default = f.default
            elif f.default_factory is not MISSING:
                default = f.default_factory()
            else:
                default = REQUIRED
            fields.append(Field(f.name, default=default, **meta))
        COMPONENTS[name] = Schema(name, help, tuple(fields), cls=cls, build=build)
        cls.component_name = name
        return cls

    return deco


def section(name: str, style: str, help: str, fields: list[Field], open_keys: bool = False) -> None:
    SECTIONS[name] = Schema(name, help, tuple(fields), open_keys=open_keys)
    SECTION_STYLE[name] = style


_loaded = False


def load_all() -> None:
    """Import every module of the `components` package so all component types are registered."""
    global _loaded
    if _loaded:
        return

    for mod in pkgutil.iter_modules(chainsim.components.__path__):
        importlib.import_module(f"chainsim.components.{mod.name}")
    _loaded = True


# -- value conversion -------------------------------------------------------------------------


class FieldError(Exception):
    """A value that does not fit its declared field; the message says what was expected."""


def _finite(v: float, what: str) -> float:
    if not math.isfinite(v):
        raise FieldError(f"must be finite, got {v!r}")
    return v


def _num(v, what="number") -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise FieldError(f"expected {what}, got {_show(v)}")
    return _finite(float(v), what)


def _show(v) -> str:
    if isinstance(v, str):
        return f"text {v!r}"
    if isinstance(v, bool):
        return f"{str(v).lower()}"
    if isinstance(v, dict):
        return "a table"
    if isinstance(v, list):
        return f"an array of {len(v)}"
    return repr(v)


def convert(f: Field, v: Any) -> Any:
    """Check `v` against field `f` and return the runtime value; raises FieldError."""
    k = f.kind
    if k in ("str", "path", "mesh", "material", "entity"):
        if not isinstance(v, str):
            raise FieldError(f"expected {KINDS[k]}, got {_show(v)}")
        out = v
    elif k == "enum":
        if v not in f.choices:
            raise FieldError(f"expected one of {', '.join(str(c) for c in f.choices if c != '')}; got {_show(v)}")
        out = v
    elif k == "int":
        if isinstance(v, bool) or not isinstance(v, int):
            raise FieldError(f"expected an integer, got {_show(v)}")
        out = v
    elif k == "float":
        out = _num(v)
    elif k == "bool":
        if not isinstance(v, bool):
            raise FieldError(f"expected true or false, got {_show(v)}")
        out = v
    elif k in ("vec2", "vec3", "vec4", "quat", "rect"):
        n = {"vec2": 2, "vec3": 3, "vec4": 4, "quat": 4, "rect": 4}[k]
        if not isinstance(v, list) or len(v) != n:
            raise FieldError(f"expected {KINDS[k]}, got {_show(v)}")
        arr = np.array([_num(c) for c in v], dtype=np.float64)
        if k == "quat":
            norm = float(np.linalg.norm(arr))
            if norm < 1e-12:
                raise FieldError("a rotation quaternion must not be zero")
            arr = arr / norm
        out = arr
    elif k in ("str_list", "int_list", "float_list"):
        if not isinstance(v, list):
            raise FieldError(f"expected {KINDS[k]}, got {_show(v)}")
        if k == "str_list":
            if not all(isinstance(c, str) for c in v):
                raise FieldError("expected an array of text")
            out = list(v)
        elif k == "int_list":
            if not all(isinstance(c, int) and not isinstance(c, bool) for c in v):
                raise FieldError("expected an array of integers")
            out = np.array(v, dtype=np.int64)
        else:
            out = np.array([_num(c) for c in v], dtype=np.float64)
    elif k == "table_list":
        if not isinstance(v, list) or not all(isinstance(c, dict) for c in v):
            raise FieldError(f"expected an array of tables, got {_show(v)}")
        out = v
    elif k == "any":
        if isinstance(v, float):
            _finite(v, "number")
        if not isinstance(v, (int, float, str, bool)):
            raise FieldError(f"expected a number, text or true/false, got {_show(v)}")
        out = v
    else:  # pragma: no cover - guarded by prop()
        raise FieldError(f"unknown kind {k}")
    if f.min is not None or f.max is not None:
        vals = np.atleast_1d(np.asarray(out, dtype=np.float64)) if k not in ("str", "enum") else []
        for x in vals:
            if f.min is not None and x < f.min:
                raise FieldError(f"must be >= {f.min:g}, got {x:g}")
            if f.max is not None and x > f.max:
                raise FieldError(f"must be <= {f.max:g}, got {x:g}")
    return out


def default_value(f: Field) -> Any:
    d = f.default
    if isinstance(d, np.ndarray):
        return d.copy()
    if isinstance(d, (list, dict)):
        return type(d)(d)
    return d

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
import re
from collections.abc import Callable, Iterable
from dataclasses import MISSING, dataclass
from typing import Any

import numpy as np

import chainsim.components
from chainsim.systems.engine import limits


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
    stride: int = 1  # a float_list's length must be a multiple of this (3: x, y, z triples)

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
    stride: int = 1,
):
    """A dataclass field that is also a manifest key (see module docstring)."""
    if kind not in KINDS:
        raise ValueError(f"unknown field kind {kind!r}")
    meta = {
        "chainsim": dict(kind=kind, units=units, help=help, choices=tuple(choices), min=min, max=max, stride=stride)
    }
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
        return cls

    return deco


def section(name: str, style: str, help: str, fields: list[Field], open_keys: bool = False) -> None:
    SECTIONS[name] = Schema(name, help, tuple(fields), open_keys=open_keys)
    SECTION_STYLE[name] = style


_loaded = False


def load_all(features: Iterable[str] = ()) -> None:
    """Register every manifest table: the shared types of this package, then each feature's modules.

    A feature declares its own component types and sections in its modules (importing one registers
    them); the composition root names the features (chainsim.game.trainer.plugins.load_manifests). A
    feature module that is missing is an error, not a smaller registry."""
    global _loaded
    for mod in pkgutil.iter_modules(chainsim.components.__path__):
        importlib.import_module(f"chainsim.components.{mod.name}")
    for name in features:
        importlib.import_module(name)
    _loaded = True


# -- value conversion -------------------------------------------------------------------------
#
# Every value is bounded (chainsim.systems.engine.limits, docs/limits.md): a field's own min/max when it
# declares them, else +-MAX_COORD for numbers and +-MAX_INT for whole numbers; text has a length
# limit and paths may not hold control characters. So a manifest can never smuggle an inf, a NaN,
# a 100-digit integer or an endless count past validation.

_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")
_NAME_KINDS = ("mesh", "material", "entity")


class FieldError(Exception):
    """A value that does not fit its declared field; the message says what was expected."""


def _show(v) -> str:
    if isinstance(v, str):
        return f"text {v[:60]!r}" + ("..." if len(v) > 60 else "")
    if isinstance(v, bool):
        return f"{str(v).lower()}"
    if isinstance(v, dict):
        return "a table"
    if isinstance(v, list):
        return f"an array of {len(v)}"
    if isinstance(v, int) and len(str(v)) > 24:
        return f"a {len(str(abs(v)))}-digit number"
    return repr(v)


def _num(v, f: Field | None = None) -> float:
    """A finite number within the field's range (its min/max, else +-MAX_COORD)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise FieldError(f"expected number, got {_show(v)}")
    try:
        x = float(v)
    except OverflowError:
        x = math.inf if v > 0 else -math.inf
    if not math.isfinite(x):
        raise FieldError(f"must be finite, got {_show(v) if isinstance(v, int) else repr(x)}")
    lo = f.min if f is not None and f.min is not None else None
    hi = f.max if f is not None and f.max is not None else None
    if lo is not None and x < lo:
        raise FieldError(f"must be >= {lo:g}, got {x:g}")
    if hi is not None and x > hi:
        raise FieldError(f"must be <= {hi:g}, got {x:g}")
    # a side the field leaves open is bounded by MAX_COORD (a declared bound replaces it: a modulus in Pa)
    if (hi is None and x > limits.MAX_COORD) or (lo is None and x < -limits.MAX_COORD):
        raise FieldError(f"must be within +-{limits.MAX_COORD:g} (docs/limits.md), got {x:g}")
    return x


def _int(v, f: Field) -> int:
    """A whole number within the field's range (its min/max, else +-MAX_INT)."""
    if isinstance(v, bool) or not isinstance(v, int):
        raise FieldError(f"expected an integer, got {_show(v)}")
    lo = int(f.min) if f.min is not None else -limits.MAX_INT
    hi = int(f.max) if f.max is not None else limits.MAX_INT
    if v < lo:
        raise FieldError(f"must be >= {lo}, got {_show(v)}")
    if v > hi:
        why = " (docs/limits.md)" if f.max is None or hi in _DOCUMENTED else ""
        raise FieldError(f"must be <= {hi}{why}, got {_show(v)}")
    return v


_DOCUMENTED = {lim.value for lim in limits.LIMITS.values()}


def _text(v, kind: str) -> str:
    if not isinstance(v, str):
        raise FieldError(f"expected {KINDS[kind]}, got {_show(v)}")
    if kind == "path":
        if len(v) > limits.MAX_PATH_LENGTH:
            raise FieldError(f"a path of {len(v)} characters is over the {limits.MAX_PATH_LENGTH}-character limit")
        if _CONTROL.search(v):
            raise FieldError(f"path {v[:60]!r} contains a control character (NUL, newline, ...); use a plain file name")
    elif kind in _NAME_KINDS:
        if len(v) > limits.MAX_KEY_LENGTH:
            raise FieldError(f"a name of {len(v)} characters is over the {limits.MAX_KEY_LENGTH}-character limit")
    elif len(v) > limits.MAX_TEXT_LENGTH:
        raise FieldError(f"text of {len(v)} characters is over the {limits.MAX_TEXT_LENGTH}-character limit")
    return v


def convert(f: Field, v: Any) -> Any:
    """Check `v` against field `f` and return the runtime value; raises FieldError."""
    k = f.kind
    out: Any
    if k in ("str", "path", "mesh", "material", "entity"):
        out = _text(v, k)
    elif k == "enum":
        if isinstance(v, (list, dict)) or v not in f.choices:
            raise FieldError(f"expected one of {', '.join(str(c) for c in f.choices if c != '')}; got {_show(v)}")
        out = v
    elif k == "int":
        out = _int(v, f)
    elif k == "float":
        out = _num(v, f)
    elif k == "bool":
        if not isinstance(v, bool):
            raise FieldError(f"expected true or false, got {_show(v)}")
        out = v
    elif k in ("vec2", "vec3", "vec4", "quat", "rect"):
        n = {"vec2": 2, "vec3": 3, "vec4": 4, "quat": 4, "rect": 4}[k]
        if not isinstance(v, list) or len(v) != n:
            raise FieldError(f"expected {KINDS[k]}, got {_show(v)}")
        arr = np.array([_num(c, f) for c in v], dtype=np.float64)
        if k == "quat":
            norm = float(np.linalg.norm(arr))
            if norm < 1e-12:
                raise FieldError("a rotation quaternion must not be zero")
            arr = arr / norm
        out = arr
    elif k in ("str_list", "int_list", "float_list"):
        if not isinstance(v, list):
            raise FieldError(f"expected {KINDS[k]}, got {_show(v)}")
        if len(v) > limits.MAX_CELLS:
            raise FieldError(f"an array of {len(v)} items is over the {limits.MAX_CELLS}-item limit")
        if k == "str_list":
            if not all(isinstance(c, str) for c in v):
                raise FieldError("expected an array of text")
            out = [_text(c, "str") for c in v]
        elif k == "int_list":
            if not all(isinstance(c, int) and not isinstance(c, bool) for c in v):
                raise FieldError("expected an array of integers")
            out = np.array([_int(c, f) for c in v], dtype=np.int64)
        else:
            out = np.array([_num(c, f) for c in v], dtype=np.float64)
            if f.stride > 1 and len(out) % f.stride:
                raise FieldError(
                    f"expected a flat list of {'x, y, z triples' if f.stride == 3 else f'groups of {f.stride}'} "
                    f"({f.stride} numbers each), got {len(out)} numbers"
                )
    elif k == "table_list":
        if not isinstance(v, list) or not all(isinstance(c, dict) for c in v):
            raise FieldError(f"expected an array of tables, got {_show(v)}")
        out = v
    elif k == "any":
        if isinstance(v, (int, float)) and not isinstance(v, bool):
            _num(v)
        elif isinstance(v, str):
            _text(v, "str")
        elif not isinstance(v, bool):
            raise FieldError(f"expected a number, text or true/false, got {_show(v)}")
        out = v
    else:  # pragma: no cover - guarded by prop()
        raise FieldError(f"unknown kind {k}")
    return out


def default_value(f: Field) -> Any:
    d = f.default
    if isinstance(d, np.ndarray):
        return d.copy()
    if isinstance(d, (list, dict)):
        return type(d)(d)
    return d

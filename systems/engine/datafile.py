"""Reading the TOML and JSON files a user hands in: pack manifests, input scripts, recordings, protocols.

One reader so every such file gets the same protection (limits in chainsim.systems.engine.limits):

- size: the file is measured before it is read (MAX_MANIFEST_BYTES, MAX_SCRIPT_BYTES);
- nesting: brackets and braces outside strings and comments are counted before the parser runs, so
  a file nested thousands deep is refused in one line instead of exhausting the parser's stack; the
  parsed structure (dotted keys included) is measured again afterwards;
- numbers: JSON's NaN/Infinity, floats that overflow to inf and integers beyond 64 bits are refused
  at parse time; TOML integers beyond TOML's own 64-bit range are refused with their key path.

Errors are `DataError` (a UserError) carrying the line and key path when known, so the pack
validator can file them as `file:line: key: message`.
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from pathlib import Path
from typing import Any

from chainsim.systems.engine import limits
from chainsim.systems.engine.errors import UserError

INT64 = 2**63


class DataError(UserError):
    """A file that cannot be read as data; `detail` is the message without the location."""

    def __init__(self, where: str, detail: str, line: int | None = None, key: str = ""):
        self.where, self.detail, self.line, self.key = where, detail, line, key
        loc = f"{where}:{line}" if line else where
        super().__init__(f"{loc}: {key}: {detail}" if key else f"{loc}: {detail}")


def read_text(path: str | Path, *, max_bytes: int, what: str = "file") -> str:
    """The UTF-8 text of `path`, refused in one line if missing, unreadable or over `max_bytes`."""
    p = Path(path)
    try:
        size = p.stat().st_size
        if not p.is_file():
            raise DataError(str(p), f"not a {what} (a folder or a special file)")
        if size > max_bytes:
            raise DataError(str(p), f"{size:,} bytes, over the {max_bytes:,}-byte limit for a {what} (docs/limits.md)")
        with p.open("rb") as fh:
            raw = fh.read(max_bytes + 1)
    except FileNotFoundError:
        raise DataError(str(p), f"{what} not found") from None
    except ValueError as e:  # an embedded NUL byte in the path
        raise DataError(repr(str(p)), f"not a usable path ({e})") from None
    except OSError as e:
        raise DataError(str(p), f"cannot read ({e.strerror or e})") from None
    if len(raw) > max_bytes:  # grew while we looked, or a special file
        raise DataError(str(p), f"over the {max_bytes:,}-byte limit for a {what}")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise DataError(str(p), "not UTF-8 text", line) from None


# -- nesting, before parsing ------------------------------------------------------------------------

_TOML_TOKENS = re.compile(
    r'"""(?:[^\\]|\\.)*?"""+|\'\'\'.*?\'\'\'+|"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*|[\[\]{}]', re.S
)
_JSON_TOKENS = re.compile(r'"(?:[^"\\]|\\.)*"|[\[\]{}]', re.S)


def _bracket_depth(text: str, tokens: re.Pattern) -> tuple[int, int]:
    """(deepest bracket nesting outside strings and comments, offset where it was reached)."""
    depth = deepest = at = 0
    for m in tokens.finditer(text):
        c = m.group()
        if c in "[{":
            depth += 1
            if depth > deepest:
                deepest, at = depth, m.start()
        elif c in "]}":
            depth -= 1
    return deepest, at


def _check_brackets(text: str, where: str, tokens: re.Pattern) -> None:
    deepest, at = _bracket_depth(text, tokens)
    if deepest > limits.MAX_NESTING:
        line = text.count("\n", 0, at) + 1
        raise DataError(where, f"nested more than {limits.MAX_NESTING} levels deep (docs/limits.md)", line)


def _walk(data: Any, where: str, *, int_range: int) -> None:
    """Depth of the parsed structure and the range of its integers, without recursion."""
    stack: list[tuple[Any, str, int]] = [(data, "", 0)]
    while stack:
        v, key, depth = stack.pop()
        if depth > limits.MAX_NESTING:
            raise DataError(where, f"nested more than {limits.MAX_NESTING} levels deep (docs/limits.md)", key=key)
        if isinstance(v, dict):
            for k, x in v.items():
                stack.append((x, f"{key}.{k}" if key else str(k), depth + 1))
        elif isinstance(v, list):
            for i, x in enumerate(v):
                stack.append((x, f"{key}.{i}" if key else str(i), depth + 1))
        elif isinstance(v, int) and not isinstance(v, bool) and not -int_range <= v < int_range:
            raise DataError(where, f"integer of {len(str(abs(v)))} digits is out of the 64-bit range", key=key)


# -- parsers ----------------------------------------------------------------------------------------


def parse_toml(text: str, where: str) -> dict:
    """TOML text -> dict, with the nesting and integer checks above."""
    _check_brackets(text, where, _TOML_TOKENS)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        msg = str(e)
        m = re.search(r"\(at line (\d+), column (\d+)\)", msg)
        detail = re.sub(r" \(at line.*", "", msg)
        raise DataError(where, f"TOML syntax error: {detail}", int(m.group(1)) if m else None) from None
    except RecursionError:  # a nesting the bracket count could not see
        raise DataError(where, f"nested more than {limits.MAX_NESTING} levels deep (docs/limits.md)") from None
    _walk(data, where, int_range=INT64)
    return data


def _json_float(s: str) -> float:
    x = float(s)
    if not math.isfinite(x):
        raise ValueError(f"number {s[:30]} is too large for a float")
    return x


def _json_int(s: str) -> int:
    if len(s.lstrip("-")) > 19 or not -INT64 <= int(s) < INT64:
        raise ValueError(f"integer {s[:30]}{'...' if len(s) > 30 else ''} is out of the 64-bit range")
    return int(s)


def _json_constant(s: str):
    raise ValueError(f"{s} is not a number JSON allows (numbers must be finite)")


def parse_json(text: str, where: str) -> Any:
    """JSON text -> data, refusing NaN/Infinity, float overflow, huge integers and deep nesting."""
    _check_brackets(text, where, _JSON_TOKENS)
    try:
        data = json.loads(text, parse_float=_json_float, parse_int=_json_int, parse_constant=_json_constant)
    except json.JSONDecodeError as e:
        raise DataError(where, f"JSON syntax error: {e.msg}", e.lineno) from None
    except RecursionError:
        raise DataError(where, f"nested more than {limits.MAX_NESTING} levels deep (docs/limits.md)") from None
    except ValueError as e:  # from the hooks above
        raise DataError(where, str(e)) from None
    _walk(data, where, int_range=INT64)
    return data


def load(path: str | Path, *, max_bytes: int = limits.MAX_SCRIPT_BYTES, what: str = "file") -> Any:
    """Read and parse a .toml file as TOML and anything else as JSON."""
    text = read_text(path, max_bytes=max_bytes, what=what)
    if Path(path).suffix.lower() == ".toml":
        return parse_toml(text, str(path))
    return parse_json(text, str(path))

"""Every limit on what a user can hand the program, in one place, with the checks that apply them.

A pack, a mesh file, an input script, a recording or a command-line flag can ask for work of any
size; each quantity a user controls has a documented upper bound here, checked before the work
starts, so bad input is one clear line (exit 2) instead of a hang, a traceback or a silent inf/NaN.
docs/limits.md is generated from `LIMITS` (`chainsim docs limits`) and a test keeps the two equal.

The checks raise `LimitError` (a ValueError) with a message that says what was expected; callers
prefix the key, flag or file the value came from and raise their own error type.
"""

from __future__ import annotations

import math
import numbers
import os
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from chainsim.systems.engine.errors import UserError


@dataclass(frozen=True, slots=True)
class Limit:
    name: str  # the constant's name in this module
    value: float
    units: str
    group: str
    what: str


LIMITS: dict[str, Limit] = {}
GROUPS = ("Counts", "Numbers and coordinates", "Meshes", "Files and nesting", "Names and text")


def _limit(name: str, value, units: str, group: str, what: str):
    assert group in GROUPS, group
    LIMITS[name] = Limit(name, value, units, group, what)
    return value


# -- counts a user can set (each one multiplies run time) --------------------------------------------
MAX_STEPS = _limit(
    "MAX_STEPS",
    1_000_000,
    "steps",
    "Counts",
    "Fixed simulation steps of one run (`--steps`, `[settings] steps`, a recording's `steps`); "
    "about 2.3 h of simulated time at 120 Hz.",
)
MAX_RELAX = _limit(
    "MAX_RELAX",
    1000,
    "iterations",
    "Counts",
    "Relaxation iterations after each cascade (`[materials] relax`, `deformable.relax`, `--relax`).",
)
MAX_BRANCH_DEPTH = _limit(
    "MAX_BRANCH_DEPTH", 64, "levels", "Counts", "Branch depth per turn of the balanced order (`deformable.depth`)."
)
MAX_REPEAT = _limit(
    "MAX_REPEAT", 1000, "runs", "Counts", "Repeats of one benchmark case or one protocol trial (`--repeat`, `repeat`)."
)
MAX_PROTOCOL_RUNS = _limit(
    "MAX_PROTOCOL_RUNS", 10_000, "runs", "Counts", "Scripted runs of one study protocol (trials x scripts x repeat)."
)
MAX_FRAMES = _limit(
    "MAX_FRAMES", 100_000, "frames", "Counts", "Frames of a render benchmark case (`--frames`, `--warmup`)."
)
MAX_BENCH_ELEMENTS = _limit(
    "MAX_BENCH_ELEMENTS",
    20_000_000,
    "elements",
    "Counts",
    "Largest generated mesh of a benchmark (`bench chainmail --max-elements`, `bench render --triangles`).",
)
MAX_EVENTS = _limit("MAX_EVENTS", 1_000_000, "events", "Counts", "Events in one input script or recording.")
MAX_REQUIRED_PACKS = _limit(
    "MAX_REQUIRED_PACKS",
    256,
    "packs",
    "Counts",
    "Packs one pack builds on, directly or through the packs those require (`[pack] requires`); each is "
    "read once, however many paths lead to it.",
)
MAX_STUDY_BLOCK = _limit(
    "MAX_STUDY_BLOCK", 16, "nodes per edge", "Counts", "Calibration block size of `study calibrate --block-n`."
)
MAX_ATTEMPT_ID = _limit(
    "MAX_ATTEMPT_ID", 2**63 - 1, "", "Counts", "Attempt ids accepted by `records show/delete` (SQLite's integer range)."
)

# -- numbers -----------------------------------------------------------------------------------------
MAX_COORD = _limit(
    "MAX_COORD",
    1.0e6,
    "mm",
    "Numbers and coordinates",
    "Largest magnitude of a coordinate (mesh vertices after unit conversion, positions, waypoints, picks, "
    "`--to`) and, on any side its key leaves open, of any number in a pack, script or recording. "
    "Squares and sums of such numbers stay far from overflow, so nothing derived becomes inf or NaN.",
)
MAX_TIME = _limit(
    "MAX_TIME", 1.0e6, "s", "Numbers and coordinates", "Event times in input scripts and recordings (`t`)."
)
MIN_DT = _limit(
    "MIN_DT", 1.0e-5, "s", "Numbers and coordinates", "Smallest fixed step (`--dt`, `[settings] dt`, recordings)."
)
MAX_DT = _limit(
    "MAX_DT", 0.1, "s", "Numbers and coordinates", "Largest fixed step (`--dt`, `[settings] dt`, recordings)."
)
MAX_INT = _limit(
    "MAX_INT",
    2**31 - 1,
    "",
    "Numbers and coordinates",
    "Largest magnitude of any other whole number in a pack, script or recording (TOML allows 64 bits; "
    "larger integers are refused before they reach numpy).",
)
MAX_PIXELS = _limit(
    "MAX_PIXELS",
    16384,
    "px",
    "Numbers and coordinates",
    "Window, frame and snapshot width or height (`--size`, `window_size`).",
)

# -- meshes ------------------------------------------------------------------------------------------
DEFAULT_MAX_MESH_MB = _limit(
    "DEFAULT_MAX_MESH_MB",
    64.0,
    "MB",
    "Meshes",
    "Default size limit of one mesh file and of the array data it declares (an .npz's uncompressed "
    "arrays, a .vtu's decompressed blocks); `CHAINSIM_MAX_MESH_MB` changes it.",
)
MAX_MESH_MB = _limit(
    "MAX_MESH_MB", 4096.0, "MB", "Meshes", "Largest value `CHAINSIM_MAX_MESH_MB` accepts (it must be a number > 0)."
)
MAX_VERTICES = _limit(
    "MAX_VERTICES",
    5_000_000,
    "vertices",
    "Meshes",
    "Vertices (ChainMail elements) of one mesh, read from a file or built as a primitive (grid, sphere, "
    "tet_block ... resolution is checked against it at validation).",
)
MAX_CELLS = _limit("MAX_CELLS", 20_000_000, "cells", "Meshes", "Triangles, tetrahedra or links of one mesh.")
MAX_RESOLUTION = _limit("MAX_RESOLUTION", 4096, "per axis", "Meshes", "Primitive `resolution` along one axis.")

# -- files and nesting -------------------------------------------------------------------------------
MAX_MANIFEST_BYTES = _limit(
    "MAX_MANIFEST_BYTES", 4 * 1024 * 1024, "bytes", "Files and nesting", "pack.toml and each included TOML file."
)
MAX_SCRIPT_BYTES = _limit(
    "MAX_SCRIPT_BYTES",
    64 * 1024 * 1024,
    "bytes",
    "Files and nesting",
    "An input script, a recording or a study protocol.",
)
#: a recording once inflated; a small upload cannot inflate into a large one (a zip bomb stops here)
MAX_RECORDING_INFLATED = 16 * 1024 * 1024
MAX_RECORDING_BYTES = _limit(
    "MAX_RECORDING_BYTES",
    768 * 1024,
    "bytes",
    "Files and nesting",
    "The recording an attempt uploads to a records server and the server keeps with it, compressed "
    f"(a long window session with mouse motion is a few 100 KiB); at most {MAX_RECORDING_INFLATED:,} bytes "
    "once inflated (`MAX_RECORDING_INFLATED`). A larger one is refused with a 422 naming the limit.",
)
MAX_NESTING = _limit(
    "MAX_NESTING",
    32,
    "levels",
    "Files and nesting",
    "Nesting of arrays and tables in TOML and JSON files (checked before parsing, so a deeply nested "
    "file cannot exhaust the parser's stack).",
)

# -- names and text ----------------------------------------------------------------------------------
MAX_NAME_LENGTH = _limit(
    "MAX_NAME_LENGTH",
    64,
    "characters",
    "Names and text",
    "Class and trainee names (`--class`, `--trainee`, `records add-*`). Control and format characters "
    "(including right-to-left overrides and zero-width marks) are refused.",
)
MAX_KEY_LENGTH = _limit(
    "MAX_KEY_LENGTH",
    128,
    "characters",
    "Names and text",
    "Names of meshes, materials, entities, scenes, layouts and other manifest tables, and short text keys.",
)
MAX_TEXT_LENGTH = _limit(
    "MAX_TEXT_LENGTH",
    20_000,
    "characters",
    "Names and text",
    "Any one text value in a pack (descriptions, instructions).",
)
MAX_PATH_LENGTH = _limit(
    "MAX_PATH_LENGTH",
    1024,
    "characters",
    "Names and text",
    "A file path inside a pack or script; paths may not contain control characters (NUL included).",
)

MESH_ENV = "CHAINSIM_MAX_MESH_MB"


class LimitError(ValueError):
    """A value outside its documented limit; the message says what is expected (no key prefix)."""


def _fmt(x) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def whole(value: object, lo: int, hi: int) -> int:
    """`value` as an int in [lo, hi]; refuses bools, fractions and anything out of range."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise LimitError(f"expected a whole number from {lo} to {hi}, got {value!r}")
    v = int(value)
    if v < lo or v > hi:
        shown = str(v) if len(str(v)) <= 24 else f"a {len(str(abs(v)))}-digit number"
        raise LimitError(f"must be from {lo} to {hi}, got {shown}")
    return v


def number(value: object, lo: float = -MAX_COORD, hi: float = MAX_COORD) -> float:
    """`value` as a finite float in [lo, hi]; refuses bools, text and non-finite values."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise LimitError(f"expected a number, got {value!r}")
    try:
        x = float(value)
    except OverflowError:
        raise LimitError(f"must be from {_fmt(lo)} to {_fmt(hi)}, got a number too large for a float") from None
    if not math.isfinite(x):
        raise LimitError(f"must be a finite number, got {x!r}")
    if x < lo or x > hi:
        raise LimitError(f"must be from {_fmt(lo)} to {_fmt(hi)}, got {x:g}")
    return x


def coordinates(arr: ArrayLike, bound: float = MAX_COORD) -> np.ndarray:
    """Check an array of coordinates: all finite and within +-bound; returns it unchanged."""
    a = np.asarray(arr)
    if a.size == 0:
        return a
    finite = np.isfinite(a)
    if not finite.all():
        rows = int((~finite.reshape(len(a), -1)).any(axis=1).sum()) if a.ndim >= 1 else 1
        raise LimitError(f"{rows} point(s) have non-finite coordinates (NaN or inf)")
    big = float(np.abs(a).max())
    if big > bound:
        raise LimitError(f"coordinates must be within +-{_fmt(bound)} mm, found {big:g}")
    return a


def max_mesh_bytes() -> int:
    """The mesh size limit in bytes: CHAINSIM_MAX_MESH_MB when set (checked), else the default."""
    raw = os.environ.get(MESH_ENV)
    if raw is None or not raw.strip():
        return int(DEFAULT_MAX_MESH_MB * 1024 * 1024)
    try:
        mb = float(raw)
    except ValueError:
        mb = math.nan
    if not (math.isfinite(mb) and 0 < mb <= MAX_MESH_MB):
        raise UserError(f"{MESH_ENV}={raw!r}: expected a number of megabytes in (0, {MAX_MESH_MB:g}]")
    return max(1, int(mb * 1024 * 1024))


def markdown(sections: Sequence[str] = ()) -> str:
    """docs/limits.md, generated from LIMITS; ``sections`` (markdown, each from its own ``## `` heading) are
    set before the closing section: limits that live outside the engine (``chainsim docs limits`` adds the
    records server's rules for input a person can make, chainsim.game.records.plausible)."""
    out = [
        "# Limits",
        "",
        "Every quantity a pack, a mesh file, an input script, a recording or a command-line flag can set",
        "has an upper bound, checked before any work starts (by `chainsim validate` for packs, by the",
        "loaders for files, by the argument parser for flags). Input beyond a limit is refused with one",
        "line naming the key, file or flag and the limit, exit code 2. This page is generated from",
        "`chainsim.systems.engine.limits` (`chainsim docs limits`); a test keeps it equal to the code.",
        "",
    ]
    for group in GROUPS:
        out += [f"## {group}", "", "| limit | value | meaning |", "|---|---|---|"]
        for lim in LIMITS.values():
            if lim.group != group:
                continue
            v = lim.value
            shown = f"{v:,}" if isinstance(v, int) else (f"{v:,.0f}" if v >= 1000 and v == int(v) else f"{v:g}")
            unit = f" {lim.units}" if lim.units else ""
            out.append(f"| `{lim.name}` | {shown}{unit} | {lim.what} |")
        out.append("")
    out += [
        "## Environment",
        "",
        f"- `{MESH_ENV}`: mesh size limit in megabytes, a number in (0, {MAX_MESH_MB:g}]; anything else",
        "  (text, `nan`, `inf`, zero or negative) is refused with one line.",
        "",
        *(line for sec in sections for line in sec.rstrip("\n").split("\n") + [""]),
        "## How the limits are tested",
        "",
        "`tests/hardening/` throws bad input at every entry point (broken packs, hostile mesh files, bad",
        "flags, malformed scripts and recordings, damaged and foreign databases, unwritable output paths)",
        "and checks for one line, exit 2, no traceback, nothing written; for packs, that `validate` fails",
        "exactly when `run` does. `tests/hardening/test_fuzz.py` fuzzes the pack loader and the mesh",
        "importers with hypothesis for a bounded time in CI; before a release, run it longer:",
        "",
        "    CHAINSIM_FUZZ_EXAMPLES=5000 python -m pytest -q tests/hardening/test_fuzz.py",
        "",
    ]
    return "\n".join(out)

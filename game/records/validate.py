"""Validation of what goes into the trainee-records store (thesis 3.3.4 assessment tool).

Everything a caller hands to ``RecordStore`` passes through here first, so a bad field becomes
one ``UserError`` line naming the field and what is expected, and nothing malformed (NaN, inf,
an unknown aid, a misspelt key) ever reaches the database.
"""

from __future__ import annotations

import json
import math
import numbers
import re
import unicodedata
from datetime import UTC, datetime
from typing import Any

from chainsim.systems.engine import limits
from chainsim.systems.engine.errors import HIDDEN_CATEGORIES, UserError, printable
from chainsim.systems.procedures import PROCEDURES, RECORDS_PROCEDURE, records_layout
from chainsim.systems.procedures.procedure import AttemptLayout

#: the attempt as the records keep it (the fixed columns' procedure, chainsim.systems.procedures)
LAYOUT = records_layout()

NAME_MAX = limits.MAX_NAME_LENGTH

# Aids of 3.3.4 / 6.1.3 whose effect on performance the thesis compares (the needle procedure names them).
AIDS = LAYOUT.aids

# What the needle tip ended on; pack-specific objects use the same lower_snake_case form.
KNOWN_TARGETS = LAYOUT.known_targets
TARGET_RE = re.compile(r"[a-z][a-z0-9_]{0,63}")
STEP_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}")

# The attempt's fixed fields (the needle procedure's columns, its declared layout LAYOUT):
# the first five metric columns and the target are required, the X-ray's cost and redirections default to 0.
_COLUMNS = tuple(c.name for c in LAYOUT.columns)
REQUIRED = ("pack", *_COLUMNS[:3], "target", *_COLUMNS[3:5])
OPTIONAL = ("created_at", "aids", "step_times", "details", *_COLUMNS[5:], "metrics")
METRIC_RE = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,63}")
MAX_METRICS = 200
FIELDS = REQUIRED + OPTIONAL

# Unicode categories a name may not hold (chainsim.systems.engine.errors.HIDDEN_CATEGORIES): controls,
# format characters (right-to-left and other bidi overrides, zero-width joiners, the BOM),
# surrogates, private use, unassigned, line and paragraph separators. They let a name display as
# something it is not. `printable` (re-exported here) shows them escaped.
_HIDDEN = HIDDEN_CATEGORIES
__all__ = ["printable"]


def clean_name(kind: str, value: Any) -> str:
    """Return ``value`` stripped and NFC-normalised, or raise if it is not a usable class/trainee/pack name."""
    if not isinstance(value, str):
        raise UserError(f"{kind} name must be text, got {type(value).__name__}")
    name = unicodedata.normalize("NFC", value.strip())
    if not name:
        raise UserError(f"{kind} name is empty; expected 1-{NAME_MAX} characters")
    if len(name) > NAME_MAX:
        raise UserError(
            f"{kind} name '{printable(name[:20])}...' is {len(name)} characters; at most {NAME_MAX} allowed"
        )
    bad = next((c for c in name if unicodedata.category(c) in _HIDDEN), None)
    if bad is not None:
        raise UserError(
            f"{kind} name '{printable(name)}' contains the invisible or control character "
            f"U+{ord(bad):04X} ({unicodedata.name(bad, unicodedata.category(bad))}); use printable text"
        )
    return name


def _number(field: str, value: Any, *, minimum: float | None = 0.0) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise UserError(f"attempt field {field!r} must be a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise UserError(f"attempt field {field!r} is {x}; expected a finite number")
    if minimum is not None and x < minimum:
        raise UserError(f"attempt field {field!r} is {x}; expected a value >= {minimum:g}")
    return x


def _count(field: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise UserError(f"attempt field {field!r} must be a whole number, got {value!r}")
    n = int(value)
    if n < 0:
        raise UserError(f"attempt field {field!r} is {n}; expected a count >= 0")
    return n


def clean_created_at(value: Any) -> str:
    """ISO-8601 UTC timestamp; stored as the caller wrote it, ``now`` when absent."""
    if value is None:
        return datetime.now(UTC).isoformat(timespec="seconds")
    if isinstance(value, datetime):
        offset = value.utcoffset()
        if offset is None or offset.total_seconds() != 0:
            raise UserError(f"attempt field 'created_at' {value!r} must be a UTC datetime")
        return value.isoformat()
    if not isinstance(value, str):
        raise UserError(f"attempt field 'created_at' must be an ISO-8601 UTC string, got {value!r}")
    text = value.strip()
    try:
        stamp = datetime.fromisoformat(text)
    except ValueError:
        raise UserError(
            f"attempt field 'created_at' {value!r} is not ISO-8601; expected e.g. 2026-01-31T09:15:00Z"
        ) from None
    offset = stamp.utcoffset()
    if offset is None or offset.total_seconds() != 0:
        raise UserError(f"attempt field 'created_at' {value!r} is not UTC; expected a 'Z' or '+00:00' suffix")
    return text


def clean_target(value: Any) -> str:
    if not isinstance(value, str) or not TARGET_RE.fullmatch(value):
        raise UserError(
            f"attempt field 'target' is {value!r}; expected one of {', '.join(sorted(KNOWN_TARGETS))}, "
            f"{LAYOUT.target_form} or another lower_snake_case object name"
        )
    return value


def clean_aids(value: Any) -> dict[str, bool]:
    """All five aids, each a bool; aids the caller leaves out were off."""
    if value is None:
        value = {}
    if not isinstance(value, dict):
        raise UserError(f"attempt field 'aids' must be an object of booleans, got {value!r}")
    unknown = sorted(set(value) - set(AIDS), key=str)
    if unknown:
        raise UserError(f"attempt field 'aids' has unknown key {unknown[0]!r}; known: {', '.join(AIDS)}")
    out = {}
    for key in AIDS:
        flag = value.get(key, False)
        if not isinstance(flag, bool):
            raise UserError(f"aid {key!r} must be true or false, got {flag!r}")
        out[key] = flag
    return out


def clean_step_times(value: Any) -> dict[str, float]:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise UserError(f"attempt field 'step_times' must map step ids to seconds, got {value!r}")
    out = {}
    for key, seconds in value.items():
        if not isinstance(key, str) or not STEP_RE.fullmatch(key):
            raise UserError(f"step id {key!r} in 'step_times' must be 1-64 letters, digits, '_', '.' or '-'")
        out[key] = _number(f"step_times.{key}", seconds)
    return out


def _plain(path: str, value: Any) -> Any:
    """JSON-ready copy of a details value; rejects non-finite numbers and non-text keys."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return _number(path, value, minimum=None)
    if isinstance(value, dict):
        out = {}
        for key, item in value.items():
            if not isinstance(key, str):
                raise UserError(f"attempt field {path!r} has a non-text key {key!r}")
            out[key] = _plain(f"{path}.{key}", item)
        return out
    if isinstance(value, (list, tuple)) or hasattr(value, "tolist"):
        items = value.tolist() if hasattr(value, "tolist") else value
        if not isinstance(items, list):
            return _plain(path, items)
        return [_plain(f"{path}[{i}]", item) for i, item in enumerate(items)]
    raise UserError(f"attempt field {path!r} holds {type(value).__name__}; expected numbers, text, lists or objects")


def clean_details(value: Any) -> dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise UserError(f"attempt field 'details' must be an object, got {value!r}")
    return _plain("details", value)


def clean_metrics(value: Any) -> dict[str, float | None]:
    """A procedure's metrics: up to MAX_METRICS names (letters, digits, _) each a finite number or None."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise UserError(f"attempt field 'metrics' must be an object of numbers, got {value!r}")
    if len(value) > MAX_METRICS:
        raise UserError(f"attempt field 'metrics' holds {len(value)} metrics; at most {MAX_METRICS}")
    out: dict[str, float | None] = {}
    for name, x in value.items():
        if not isinstance(name, str) or not METRIC_RE.fullmatch(name):
            raise UserError(f"metric name {name!r} must be letters, digits and _ (up to 64), starting with a letter")
        out[name] = None if x is None else _number(f"metrics.{name}", x, minimum=None)
    return out


def clean_attempt(attempt: Any) -> dict[str, Any]:
    """Validated, normalised copy of an attempt dict, ready to store. An attempt names its procedure in
    `procedure` (absent: the records' procedure, whose fixed fields every attempt had before)."""
    if not isinstance(attempt, dict):
        raise UserError(f"an attempt must be a dict of fields, got {type(attempt).__name__}")
    if attempt.get("procedure", RECORDS_PROCEDURE.name) != RECORDS_PROCEDURE.name:
        return _clean_figures(attempt, _layout_of(attempt["procedure"]))
    attempt = {k: v for k, v in attempt.items() if k != "procedure"}
    unknown = sorted(set(attempt) - set(FIELDS), key=str)
    if unknown:
        raise UserError(f"attempt has unknown field {unknown[0]!r}; known: {', '.join(FIELDS)}")
    missing = [f for f in REQUIRED if f not in attempt]
    if missing:
        raise UserError(f"attempt is missing field {missing[0]!r}; required: {', '.join(REQUIRED)}")
    mark, needle = attempt[LAYOUT.mark_error], attempt[LAYOUT.target_error]
    return {
        "pack": clean_name("pack", attempt["pack"]),
        "created_at": clean_created_at(attempt.get("created_at")),
        "duration_s": _number("duration_s", attempt["duration_s"]),
        LAYOUT.mark_error: _number(LAYOUT.mark_error, mark),
        # 6.1.5 scores the needle as distance-to-centre minus the target's radius, so a tip inside
        # the opening is legitimately negative; None means the needle never touched anything.
        LAYOUT.target_error: None if needle is None else _number(LAYOUT.target_error, needle, minimum=None),
        "target": clean_target(attempt["target"]),
        "skull_contacts": _count("skull_contacts", attempt["skull_contacts"]),
        "path_length_mm": _number("path_length_mm", attempt["path_length_mm"]),
        "redirections": _count("redirections", attempt.get("redirections", 0)),
        "xray_shots": _count("xray_shots", attempt.get("xray_shots", 0)),
        "exposure_s": _number("exposure_s", attempt.get("exposure_s", 0.0)),
        "dose_mgy": _number("dose_mgy", attempt.get("dose_mgy", 0.0)),
        "aids": clean_aids(attempt.get("aids")),
        "step_times": clean_step_times(attempt.get("step_times")),
        "details": clean_details(attempt.get("details")),
        "metrics": clean_metrics(attempt.get("metrics")),
    }


def _layout_of(name: Any) -> AttemptLayout:
    proc = PROCEDURES.get(name) if isinstance(name, str) else None
    if proc is None or proc.layout is None:
        keep = sorted(k for k, p in PROCEDURES.items() if p.layout is not None)
        raise UserError(
            f"attempt field 'procedure' is {printable(str(name))[:64]!r}; attempts are kept of: {', '.join(keep)}"
        )
    return proc.layout


def _clean_figures(attempt: dict, layout: AttemptLayout) -> dict[str, Any]:
    """An attempt of a procedure other than the records' one: its layout's figures, all required."""
    figures = tuple(c.name for c in layout.columns)
    known = ("procedure", "pack", "created_at", *figures, "target", "aids", "step_times", "details", "metrics")
    unknown = sorted(set(attempt) - set(known), key=str)
    if unknown:
        raise UserError(f"attempt has unknown field {unknown[0]!r}; known: {', '.join(known)}")
    required = ("pack", *figures, "target")
    missing = [f for f in required if f not in attempt]
    if missing:
        raise UserError(f"attempt is missing field {missing[0]!r}; required: {', '.join(required)}")
    if attempt.get("aids") not in (None, {}):
        raise UserError(f"attempt field 'aids': the {attempt['procedure']} procedure records no aids")
    return {
        "procedure": attempt["procedure"],
        "pack": clean_name("pack", attempt["pack"]),
        "created_at": clean_created_at(attempt.get("created_at")),
        **{c.name: (_count if c.whole else _number)(c.name, attempt[c.name]) for c in layout.columns},
        "target": clean_target(attempt["target"]),
        "aids": {},
        "step_times": clean_step_times(attempt.get("step_times")),
        "details": clean_details(attempt.get("details")),
        "metrics": clean_metrics(attempt.get("metrics")),
    }


QUESTIONNAIRE_KINDS = ("pre", "post")
ANSWER_MAX = 500


def clean_questionnaire(kind: Any, session: Any, answers: Any) -> tuple[str, str, dict[str, Any]]:
    """A study questionnaire: its kind ('pre' or 'post'), its session label and the answers (question id ->
    a number, a short text or None for no answer)."""
    if kind not in QUESTIONNAIRE_KINDS:
        raise UserError(f"questionnaire kind is {kind!r}; expected one of {', '.join(QUESTIONNAIRE_KINDS)}")
    session = clean_name("session", session)
    if not isinstance(answers, dict):
        raise UserError(f"questionnaire answers must be an object, got {type(answers).__name__}")
    out: dict[str, Any] = {}
    for key, value in answers.items():
        if not isinstance(key, str) or not STEP_RE.fullmatch(key):
            raise UserError(f"question id {key!r} must be 1-64 letters, digits, '_', '.' or '-'")
        if value is None or isinstance(value, bool):
            out[key] = value
        elif isinstance(value, numbers.Real):
            out[key] = _number(f"answers.{key}", value, minimum=None)
        elif isinstance(value, str):
            hidden = any(unicodedata.category(c) in _HIDDEN for c in value if c != "\n")
            if len(value) > ANSWER_MAX or hidden:
                raise UserError(f"answer {key!r} must be printable text of at most {ANSWER_MAX} characters")
            out[key] = value
        else:
            raise UserError(f"answer {key!r} holds {type(value).__name__}; expected a number, text or nothing")
    return kind, session, out


KEY_RE = re.compile(r"[A-Za-z0-9_\-]{8,128}")


def clean_key(value: Any) -> str:
    """An idempotency key: 8-128 letters, digits, '_' or '-' (a UUID fits)."""
    if not isinstance(value, str) or not KEY_RE.fullmatch(value):
        shown = value[:40] + "..." if isinstance(value, str) and len(value) > 40 else value
        raise UserError(f"idempotency key {shown!r} must be 8-128 letters, digits, '_' or '-'")
    return value


def to_json(value: Any) -> str:
    return json.dumps(value, sort_keys=True, allow_nan=False, separators=(",", ":"))

"""A validity study's data: who is a novice and who an expert, and which attempts count, per participant.

Groups come from a register (a CSV a programme keeps: participant, group, year_of_training,
procedures_performed) or, without one, from the attempts themselves: an attempt's
``details.protocol`` may carry ``group`` (and ``year_of_training``, ``procedures_performed``), as the
synthetic cohort's do. A register, when given, decides every participant's group.

A participant is ``details.protocol.participant`` where the attempt was made in a study (``chainsim
protocol``), else the trainee it was saved under. Attempts of another pack, study, task or condition,
retracted ones and ones whose input was flagged and not accepted (``in_class_figures``), and those of
participants with no group, are left out and counted. An attempt made by a script (``scripted``) or
drawn by the synthetic cohort builder (``synthetic``) is counted as such: the report then says its data
are not evidence.
"""

from __future__ import annotations

import csv
import io
import math
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from chainsim.game.records.store import in_class_figures
from chainsim.game.records.validate import clean_name
from chainsim.systems.engine import datafile
from chainsim.systems.engine.errors import UserError, printable

GROUPS = ("novice", "expert")
REGISTER_COLUMNS = ("participant", "group", "year_of_training", "procedures_performed")
#: how a participant's attempts become their one value per metric
UNITS = ("median", "first", "last")
#: the largest register file read (a programme's cohort is a few hundred rows)
REGISTER_MAX_BYTES = 1024 * 1024
#: the most problems a register error lists before it counts the rest
MAX_PROBLEMS = 50
#: the whole-number columns of a register and their largest value
_COUNTS = {"year_of_training": 80, "procedures_performed": 1_000_000}


@dataclass(frozen=True)
class Participant:
    """A participant's experience: their group and, where known, their years of training and procedures."""

    name: str
    group: str
    year_of_training: int | None = None
    procedures_performed: int | None = None


class RegisterError(UserError):
    """A register with problems: one line for each (up to MAX_PROBLEMS)."""

    def __init__(self, path: str, problems: list[str]):
        shown = [f"{path}: {p}" for p in problems[:MAX_PROBLEMS]]
        if len(problems) > MAX_PROBLEMS:
            shown.append(f"{path}: ... and {len(problems) - MAX_PROBLEMS} more problems")
        self.problems = shown
        super().__init__("\n".join(shown))

    def lines(self) -> list[str]:
        return [printable(p) for p in self.problems]


def _count(column: str, text: str) -> tuple[int | None, str | None]:
    """A register's whole-number cell: (value, None), (None, None) when blank, or (None, problem)."""
    text = text.strip()
    if not text:
        return None, None
    top = _COUNTS[column]
    if not text.isdigit() or int(text) > top:
        return None, f"{column} is {text[:30]!r}; expected a whole number from 0 to {top}, or blank when unknown"
    return int(text), None


def _header_problems(header: list[str] | None) -> list[str]:
    if not header:
        return ["no header row; expected the columns " + ", ".join(REGISTER_COLUMNS)]
    names = [h.strip() for h in header]
    out = [f"missing column '{c}'" for c in REGISTER_COLUMNS if c not in names]
    out += [
        f"unknown column '{h[:40]}'; expected {', '.join(REGISTER_COLUMNS)}" for h in names if h not in REGISTER_COLUMNS
    ]
    out += [f"column '{h}' given twice" for h, n in Counter(names).items() if n > 1 and h in REGISTER_COLUMNS]
    return out


def _row(line: int, cells: dict[str, str], seen: dict[str, int]) -> tuple[Participant | None, str | None]:
    """One register row as a participant, or the row's problems said in one line."""
    try:
        name = clean_name("participant", cells.get("participant") or "")
    except UserError as e:
        return None, f"line {line}: {e}"
    if name in seen:
        return None, f"line {line}: participant {name!r} is already on line {seen[name]}"
    seen[name] = line
    problems = []
    group = (cells.get("group") or "").strip().lower()
    if group not in GROUPS:
        problems.append(f"group is {(cells.get('group') or '')[:30]!r}; expected novice or expert")
    counts = {}
    for column in _COUNTS:
        counts[column], problem = _count(column, cells.get(column) or "")
        if problem:
            problems.append(problem)
    if problems:
        return None, f"line {line}: participant {name!r}: " + "; ".join(problems)
    return Participant(name, group, **counts), None


def parse_register(text: str, path: str) -> dict[str, Participant]:
    """Participants by name from a register's CSV text; every problem, one line each, as a RegisterError."""
    reader = csv.reader(io.StringIO(text.lstrip("\ufeff")))
    header = next(reader, None)
    problems = _header_problems(header)
    if problems:
        raise RegisterError(path, problems)
    assert header is not None
    names = [h.strip() for h in header]
    out: dict[str, Participant] = {}
    seen: dict[str, int] = {}
    for cells in reader:
        line = reader.line_num
        if not any(c.strip() for c in cells):
            continue  # a blank line, as spreadsheets leave at the end
        if len(cells) != len(names):
            problems.append(f"line {line}: {len(cells)} cell{'s' * (len(cells) != 1)}; the header has {len(names)}")
            continue
        p, problem = _row(line, dict(zip(names, cells)), seen)
        if problem:
            problems.append(problem)
        if p is not None:
            out[p.name] = p
    if not out and not problems:
        problems.append("no participants; expected one row per participant under the header")
    if problems:
        raise RegisterError(path, problems)
    return out


def read_register(path: str | Path) -> dict[str, Participant]:
    """The register file at `path` (UTF-8 CSV, at most REGISTER_MAX_BYTES)."""
    text = datafile.read_text(path, max_bytes=REGISTER_MAX_BYTES, what="register")
    try:
        return parse_register(text, str(path))
    except csv.Error as e:
        raise UserError(f"{path}: not a readable CSV ({e})") from None


def protocol(attempt: dict[str, Any]) -> dict[str, Any]:
    p = (attempt.get("details") or {}).get("protocol")
    return p if isinstance(p, dict) else {}


def participant_of(attempt: dict[str, Any]) -> str:
    """Who made the attempt: the study's participant, else the trainee it was saved under."""
    name = protocol(attempt).get("participant")
    return name if isinstance(name, str) and name else str(attempt.get("trainee") or "")


def is_synthetic(attempt: dict[str, Any]) -> bool:
    """Made by an input script or drawn by the synthetic cohort builder, not by a person."""
    p = protocol(attempt)
    return bool(p.get("scripted")) or bool(p.get("synthetic"))


def metric_value(attempt: dict[str, Any], name: str) -> float | None:
    """The attempt's value of metric `name` (its metrics table, else a fixed field of that name)."""
    metrics = attempt.get("metrics") or {}
    v = metrics.get(name, attempt.get(name))
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return None
    return float(v)


@dataclass
class Selection:
    """The attempts a report uses, per participant (oldest first), and what was left out and why."""

    series: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    participants: dict[str, Participant] = field(default_factory=dict)
    left_out: Counter = field(default_factory=Counter)
    ungrouped: set[str] = field(default_factory=set)
    absent: list[str] = field(default_factory=list)
    synthetic: int = 0
    sources: Counter = field(default_factory=Counter)
    groups_from: str = "register"

    @property
    def attempts(self) -> int:
        return sum(len(v) for v in self.series.values())

    def in_group(self, group: str) -> list[str]:
        return sorted(p for p in self.series if self.participants[p].group == group)


def _filtered(attempts: Iterable[dict[str, Any]], pack: str, narrow: dict[str, str | None], sel: Selection):
    """The attempts of `pack` whose details.protocol matches every key of `narrow` given (study, task,
    condition) and that count in a class's figures; the rest counted in `sel.left_out` by reason."""
    for a in attempts:
        p = protocol(a)
        other = next((k for k, v in narrow.items() if v is not None and p.get(k) != v), None)
        if a.get("pack") != pack:
            sel.left_out["of another pack"] += 1
        elif other is not None:
            sel.left_out[f"of another {other} (or none)"] += 1
        elif p.get("practice"):
            sel.left_out["practice trials"] += 1
        elif not in_class_figures(a):
            sel.left_out["retracted, or flagged and not accepted"] += 1
        else:
            yield a


def _group_from_attempts(name: str, attempts: list[dict[str, Any]]) -> Participant | None:
    """The group the participant's attempts record (details.protocol.group); None when none does."""
    found = {str(g) for a in attempts if (g := protocol(a).get("group")) is not None}
    if not found:
        return None
    if len(found) > 1 or not found <= set(GROUPS):
        shown = ", ".join(sorted(found))
        raise UserError(
            f"participant {name!r}: their attempts record the group {shown}; expected novice or expert "
            "(or give --groups FILE)"
        )
    p = protocol(attempts[-1])
    counts = {k: p.get(k) if isinstance(p.get(k), int) and not isinstance(p.get(k), bool) else None for k in _COUNTS}
    return Participant(name, found.pop(), **counts)


def select(
    attempts: Iterable[dict[str, Any]],
    register: dict[str, Participant] | None,
    *,
    pack: str,
    study: str | None = None,
    task: str | None = None,
    condition: str | None = None,
) -> Selection:
    """The attempts of `pack` (and `study`, `task`, `condition`) by participants with a group, oldest first."""
    sel = Selection(groups_from="register" if register is not None else "attempts")
    by_person: dict[str, list[dict[str, Any]]] = {}
    narrow = {"study": study, "task": task, "condition": condition}
    for a in _filtered(attempts, pack, narrow, sel):
        by_person.setdefault(participant_of(a), []).append(a)
    for name, own in by_person.items():
        person = register.get(name) if register is not None else _group_from_attempts(name, own)
        if person is None:
            sel.ungrouped.add(name)
            sel.left_out["by participants with no group"] += len(own)
            continue
        own.sort(key=lambda a: (str(a.get("created_at") or ""), a.get("id") or 0))
        sel.series[name], sel.participants[name] = own, person
        sel.synthetic += sum(is_synthetic(a) for a in own)
        sel.sources.update(str(a.get("source") or "local") for a in own)
    sel.absent = sorted(set(register or {}) - set(sel.series))
    return sel


def participant_value(values: list[float | None], unit: str) -> float | None:
    """A participant's one value from their attempts' values (oldest first): median, first or last."""
    xs = [v for v in values if v is not None]
    if not xs:
        return None
    if unit == "first":
        return xs[0]
    if unit == "last":
        return xs[-1]
    xs.sort()
    mid = len(xs) // 2
    return xs[mid] if len(xs) % 2 else (xs[mid - 1] + xs[mid]) / 2

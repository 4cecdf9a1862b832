"""A programme's own benchmarks from a validity study: the contrasting-groups pass marks of
``chainsim study-report`` as [metrics.NAME] tables, with where each came from.

Every report writes ``benchmarks.toml`` beside report.md: one table per metric that separates the
groups and has a pass mark (``benchmark``, ``benchmark_basis = "programme"`` and a
``benchmark_source`` naming the data: "programme data: N novices / M experts, DATE, study NAME"),
the other metrics as comments saying why they have none. A programme reviews the false-pass and
false-fail rates and adopts the marks it accepts, by hand or with ``--write-benchmarks PACK_DIR``
(``apply``): the named pack's pack.toml gets those three keys in each table, its old text is kept
as pack.toml.bak, the pack is validated again (the old text put back on any problem), and a
built-in pack is never rewritten: a programme copies it first. Marks from synthetic data are
written as provisional, never applied.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from chainsim.game.study.validity_report import SYNTHETIC, Study, percent
from chainsim.systems.engine import atomicfile
from chainsim.systems.engine.errors import UserError

FILE = "benchmarks.toml"
#: the keys a programme's benchmark sets in its [metrics.NAME] table, in the order written
KEYS = ("benchmark", "benchmark_basis", "benchmark_source")


@dataclass
class Proposal:
    """One metric's benchmark as a programme would adopt it."""

    name: str
    benchmark: float
    basis: str
    source: str

    def values(self) -> dict[str, str]:
        """Each key's TOML value text."""
        return {
            "benchmark": repr(self.benchmark),
            "benchmark_basis": toml_string(self.basis),
            "benchmark_source": toml_string(self.source),
        }


def toml_string(text: str) -> str:
    """A TOML basic string on one line."""
    escaped = text.replace("\\", "\\\\").replace('"', '\\"')
    return '"' + "".join(c if c.isprintable() else f"\\u{ord(c):04x}" for c in escaped) + '"'


def proposals(study: Study, study_name: str, day: str) -> tuple[list[Proposal], dict[str, str]]:
    """The marks a programme may adopt (metrics that separate the groups and have a mark), and for
    every other metric why it has none. `study_name` names the data (a study, a class), `day` the date."""
    out, none = [], {}
    for r in study.results:
        m = r.mark
        if not r.separates:
            none[r.name] = "does not separate the groups in these data"
        elif m.get("mark") is None:
            none[r.name] = f"no contrasting-groups mark ({m.get('why', 'too few participants')})"
        else:
            data = f"{len(r.novice)} novices / {len(r.expert)} experts, {day}, {study_name}"
            rates = f"false pass {percent(m['false_pass'])}, false fail {percent(m['false_fail'])} fitted"
            how = f"contrasting-groups pass mark, {rates} (chainsim study-report)"
            if study.synthetic:
                out.append(Proposal(r.name, float(f"{m['mark']:.3g}"), "provisional", f"{SYNTHETIC}: {data}; {how}"))
            else:
                out.append(Proposal(r.name, float(f"{m['mark']:.3g}"), "programme", f"programme data: {data}; {how}"))
    return out, none


def toml_text(study: Study, marks: list[Proposal], none: dict[str, str]) -> str:
    """benchmarks.toml: the proposals as [metrics.NAME] tables, the rest as comments."""
    lines = [
        f"# Benchmarks from chainsim study-report, pack {study.pack}: contrasting-groups pass marks of the",
        "# metrics that separate novices from experts. Review each mark's false-pass and false-fail rates",
        "# (report.md), then adopt those you accept: copy their keys into the same [metrics.NAME] tables of",
        "# your copy of the pack, or run chainsim study-report again with --write-benchmarks PACK_DIR.",
        f"# Data: {study.source}",
    ]
    if study.synthetic:
        lines.append(f"# {SYNTHETIC.upper()}: these marks are provisional and are never written into a pack.")
    for p in marks:
        lines += ["", f"[metrics.{p.name}]"] + [f"{k} = {v}" for k, v in p.values().items()]
    if none:
        lines.append("")
    lines += [f"# {name}: no mark, {why}" for name, why in none.items()]
    return "\n".join(lines) + "\n"


def _table_span(lines: list[str], name: str) -> tuple[int, int]:
    """The lines of [metrics.NAME]: its header's index and the index after its last line."""
    header = re.compile(rf"\s*\[\s*metrics\s*\.\s*\"?{re.escape(name)}\"?\s*\]\s*(#.*)?$")
    start = next((i for i, ln in enumerate(lines) if header.match(ln)), None)
    if start is None:
        raise UserError(
            f"pack.toml has no [metrics.{name}] table to set the benchmark in; add the keys by hand from {FILE}"
        )
    end = next((i for i in range(start + 1, len(lines)) if lines[i].lstrip().startswith("[")), len(lines))
    return start, end


def edited(text: str, marks: list[Proposal]) -> str:
    """pack.toml's text with each proposal's keys set in its [metrics.NAME] table (replaced where the
    table has them, else added after its last benchmark key or its header); nothing else changes."""
    lines = text.split("\n")
    for p in marks:
        start, end = _table_span(lines, p.name)
        for key, value in p.values().items():
            pattern = re.compile(rf"\s*{key}\s*=")
            at = next((i for i in range(start + 1, end) if pattern.match(lines[i])), None)
            if at is not None:
                if '"""' in lines[at] or "'''" in lines[at]:
                    raise UserError(f"[metrics.{p.name}] {key} is a multi-line string; set it by hand from {FILE}")
                lines[at] = f"{key} = {value}"
                continue
            after = max([i for i in range(start + 1, end) if re.match(r"\s*benchmark\w*\s*=", lines[i])], default=start)
            lines.insert(after + 1, f"{key} = {value}")
            end += 1
    return "\n".join(lines)


def apply(pack_dir: Path, marks: list[Proposal], check) -> Path:
    """Write `marks` into pack_dir/pack.toml, keeping its old text as pack.toml.bak; `check(pack_dir)`
    returns the pack's problems after the edit, and on any the old text is put back and the first is
    raised. Returns the backup's path."""
    manifest = pack_dir / "pack.toml"
    try:
        old = manifest.read_text(encoding="utf-8")
    except OSError as e:
        raise UserError(f"--write-benchmarks {pack_dir}: cannot read pack.toml ({e.strerror or e})") from None
    new = edited(old, marks)
    backup = pack_dir / "pack.toml.bak"
    try:
        atomicfile.write_text(backup, old)
        atomicfile.write_text(manifest, new)
    except OSError as e:
        raise UserError(f"--write-benchmarks {pack_dir}: cannot write ({e.strerror or e})") from None
    problems = check(pack_dir)
    if problems:
        atomicfile.write_text(manifest, old)
        raise UserError(
            f"--write-benchmarks {pack_dir}: the edited pack does not validate, left as it was: {problems[0]}"
        )
    return backup

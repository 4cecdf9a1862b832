"""`chainsim validate` on what a benchmark rests on: an unknown benchmark_basis, or a published or
programme benchmark without its source, is one line naming the key and what is expected (exit 2)."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

from chainsim.game.packs.pack import load
from chainsim.systems.procedures import verdicts as vd

REPO = Path(__file__).resolve().parents[2]


def pack_with(tmp_path: Path, **basis: tuple[str, str]) -> Path:
    """A copy of mental-block whose metrics get (benchmark_basis, benchmark_source) as given."""
    copy = tmp_path / "mental-block"
    shutil.copytree(REPO / "assets" / "mental-block", copy)
    text = (copy / "pack.toml").read_text()
    for name, (kind, source) in basis.items():
        table = re.search(rf"\[metrics\.{name}\]\n(.*?)\n\n", text, re.S)
        body = re.sub(r'benchmark_basis = ".*"', f'benchmark_basis = "{kind}"', table.group(1))
        body = re.sub(r'benchmark_source = ".*"', f'benchmark_source = "{source}"', body)
        text = text.replace(table.group(1), body)
    (copy / "pack.toml").write_text(text)
    return copy


def test_a_bad_basis_and_a_published_benchmark_without_its_source_are_one_line_each(cli, tmp_path):
    code, _, err = cli("validate", pack_with(tmp_path / "a", redirections=("peer-reviewed", "x")))
    lines = err.strip().splitlines()
    assert code == 2 and "Traceback" not in err and len(lines) == 2, err
    assert "metrics.redirections.benchmark_basis: expected one of provisional, published, programme" in lines[0]
    assert "got text 'peer-reviewed'" in lines[0]
    code, _, err = cli("validate", pack_with(tmp_path / "b", duration_s=("published", "")))
    lines = err.strip().splitlines()
    assert code == 2 and "Traceback" not in err and len(lines) == 2, err
    assert "metrics.duration_s.benchmark_source: benchmark_basis 'published' needs a benchmark_source" in lines[0]


def test_a_programme_benchmark_with_its_source_validates_and_is_no_longer_provisional(cli, tmp_path):
    copy = pack_with(tmp_path, duration_s=("programme", "programme data: 9 novices / 9 experts, 2026-01-05"))
    code, out, err = cli("validate", copy)
    assert code == 0, err
    rows = {r["name"]: r for r in vd.verdicts(load(copy).section("metrics"), {"duration_s": 10.0})}
    assert rows["duration_s"]["basis"] == "programme" and rows["redirections"]["basis"] == "provisional"
    assert rows["duration_s"]["source"].startswith("programme data: 9 novices")

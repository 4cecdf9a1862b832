"""Tables on the window's pages (the F1 key page, the packs' help pages) as laid out for drawing:
each header cell is drawn once, in its own column, on a shaded box of its own, at any width."""

from __future__ import annotations

from pathlib import Path

import pytest

from chainsim.systems.view.ui import keyhelp
from chainsim.systems.view.ui import markdown as md

ROOT = Path(__file__).resolve().parents[2]
PAGES = sorted((ROOT / "assets").glob("*/docs/*.md"))


def measure(text: str, style: str) -> float:
    """7 px a character, bold a tenth wider (the window's bold is drawn twice a pixel apart)."""
    return 7.0 * len(text) * (1.1 if style == "bold" else 1.0)


def header_lines(markdown: str, width: float) -> list[tuple[list[str], list[md.Line]]]:
    """Per table of the page: its header cells' text and the laid-out lines of its header row."""
    out = []
    for block in md.parse(markdown):
        if block.kind == "table":
            lines = md.layout([block], width, measure, lambda style: 16.0)
            cells = ["".join(sp.text for sp in cell) for cell in block.rows[0]]
            out.append((cells, [ln for ln in lines if ln.boxes and ln.boxes[0][2] == "head"]))
    return out


def assert_each_header_cell_drawn_once(cells: list[str], head: list[md.Line]) -> None:
    assert head, "no header row laid out"
    for ln in head:
        assert [b[2] for b in ln.boxes] == ["head"] * len(cells), ln.boxes  # one shaded box per column
        edges = [(x, x + w) for x, w, _ in ln.boxes]
        assert all(a[1] <= b[0] + 1e-9 for a, b in zip(edges, edges[1:], strict=False)), edges
        runs = [(r.x, r.x + measure(r.text, r.style)) for r in ln.runs]
        assert all(a[1] <= b[0] + 1e-9 for a, b in zip(runs, runs[1:], strict=False)), ln.runs  # nothing overdrawn
    for c, (x, w, _) in enumerate(head[0].boxes):
        drawn = [r.text for ln in head for r in ln.runs if x <= r.x < x + w]
        # the cell's words, wrapped or cut over the header's lines, each once
        assert "".join(drawn).replace(" ", "") == cells[c].replace(" ", ""), (cells[c], drawn)
    assert len(cells) == len(head[0].boxes)


@pytest.mark.parametrize("width", [120.0, 260.0, 700.0])
def test_the_key_page_draws_each_header_cell_once(width):
    page = keyhelp.keys_markdown([{"name": "help", "key": "h", "label": "Help"}], [("`n`", "next step")], ["Howto"])
    (cells, head), *more = header_lines(page, width)
    assert not more and cells == ["Keys or mouse", "What it does"]
    assert_each_header_cell_drawn_once(cells, head)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: f"{p.parts[-3]}/{p.name}")
@pytest.mark.parametrize("width", [300.0, 700.0])
def test_every_help_page_table_draws_each_header_cell_once(page, width):
    for cells, head in header_lines(page.read_text(encoding="utf-8"), width):
        assert_each_header_cell_drawn_once(cells, head)


def test_a_header_without_its_closing_bar_or_with_an_escaped_bar_has_its_own_cells():
    for text, cells in (
        ("| Key | What it does\n|---|---|\n| a | b |\n", ["Key", "What it does"]),
        ("| Key | a \\| b |\n|---|---|\n| a | b |\n", ["Key", "a | b"]),
        ("| Key | Does |   \n| --- | :---: |\n| a | b |\n", ["Key", "Does"]),
    ):
        ((got, head),) = header_lines(text, 500.0)
        assert got == cells
        assert_each_header_cell_drawn_once(got, head)

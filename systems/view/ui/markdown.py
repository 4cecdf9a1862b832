"""Markdown for the in-app pages and overlays: parsing into blocks and laying them out into lines.

The pack's docs pages (and the F1 key overlay) are small Markdown files. This module turns them into
what a screen shows - headings, paragraphs with bold, italic and code spans, bullet and numbered
lists, tables with wrapped cells, indented code - as positioned text runs, without any GL: the caller
passes a `measure(text, style)` function in pixels and draws the result (chainsim.game.render.docview).

Supported: ATX headings (#, ##, ###), paragraphs (joined lines), `-`/`*` bullets and `1.` numbered
items (continuation lines indented), pipe tables with a `|---|` separator row, code blocks indented
by four spaces or fenced with ```, `**bold**`, `*italic*`/`_italic_`, `` `code` ``, `[text](link)`
(the text is kept) and backslash escapes (`\\|`, `\\*`).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field

Measure = Callable[[str, str], float]


@dataclass(slots=True)
class Span:
    text: str
    style: str = "body"


@dataclass(slots=True)
class Block:
    kind: str  # heading, para, bullet, number, table, code, blank
    spans: list[Span] = field(default_factory=list)
    level: int = 0  # heading level
    marker: str = ""  # list marker ("•", "3.")
    rows: list[list[list[Span]]] = field(default_factory=list)  # table: rows of cells of spans
    text: str = ""  # code


@dataclass(slots=True)
class Run:
    x: float  # pixels from the left edge of the text area
    text: str
    style: str


@dataclass(slots=True)
class Line:
    """One row of the laid-out page: text runs and, for tables, cell boxes drawn under them."""

    height: float
    runs: list[Run] = field(default_factory=list)
    boxes: list[tuple[float, float, str]] = field(default_factory=list)  # (x, width, "head" | "cell")
    grid: bool = False  # draw the cell borders of `boxes`
    style: str = "body"  # the tallest style on the line (headings)


# -- parsing --------------------------------------------------------------------------------------

_INLINE = re.compile(
    r"\\(.)|\*\*(.+?)\*\*|__(.+?)__|\*(?!\s)(.+?)(?<!\s)\*|(?<!\w)_(?!\s)(.+?)(?<!\s)_(?!\w)|`([^`]+)`|\[([^\]]+)\]\([^)]*\)"
)


def inline(text: str, base: str = "body") -> list[Span]:
    """Spans of one line of Markdown text: emphasis, code, links, escapes."""
    out: list[Span] = []

    def add(t: str, style: str) -> None:
        if not t:
            return
        if out and out[-1].style == style:
            out[-1].text += t
        else:
            out.append(Span(t, style))

    pos = 0
    for m in _INLINE.finditer(text):
        add(text[pos : m.start()], base)
        esc, bold, bold2, ital, ital2, code, link = m.groups()
        if esc is not None:
            add(esc, base)
        elif bold is not None or bold2 is not None:
            for sp in inline(bold if bold is not None else bold2, "bold" if base == "body" else base):
                add(sp.text, "bolditalic" if sp.style == "italic" else sp.style)
        elif ital is not None or ital2 is not None:
            for sp in inline(ital if ital is not None else ital2, "italic" if base == "body" else base):
                add(sp.text, "bolditalic" if sp.style == "bold" else sp.style)
        elif code is not None:
            add(code, "code")
        else:
            for sp in inline(link, base):
                add(sp.text, sp.style)
        pos = m.end()
    add(text[pos:], base)
    return out


def _cells(row: str) -> list[str]:
    """Split a table row on unescaped pipes."""
    row = row.strip()
    if row.startswith("|"):
        row = row[1:]
    if row.endswith("|") and not row.endswith("\\|"):
        row = row[:-1]
    return [c.strip() for c in re.split(r"(?<!\\)\|", row)]


_SEP = re.compile(r"^\s*\|?\s*:?-{2,}:?\s*(\|\s*:?-{2,}:?\s*)*\|?\s*$")
_BULLET = re.compile(r"^(\s*)[-*+]\s+(.*)$")
_NUMBER = re.compile(r"^(\s*)(\d+)[.)]\s+(.*)$")


def _table_at(lines: list[str], i: int) -> tuple[Block, int]:
    """The table whose header is lines[i] (its separator row next); (block, the line after it)."""
    rows = [[inline(c) for c in _cells(lines[i].rstrip())]]
    i += 2
    while i < len(lines) and lines[i].strip().startswith("|"):
        rows.append([inline(c) for c in _cells(lines[i])])
        i += 1
    return Block("table", rows=rows), i


def _item_at(lines: list[str], i: int, m: re.Match, bullet: bool) -> tuple[Block, int]:
    """The list item at lines[i] (`m`: its marker matched) with its continuation lines; (block, the
    line after it)."""
    indent = len(m.group(1))
    text = [m.group(2) if bullet else m.group(3)]
    i += 1
    # continuation lines: indented further than the marker, not a new item
    while (
        i < len(lines)
        and lines[i].strip()
        and len(lines[i]) - len(lines[i].lstrip()) > indent
        and not _BULLET.match(lines[i])
        and not _NUMBER.match(lines[i])
    ):
        text.append(lines[i].strip())
        i += 1
    kind, marker = ("bullet", "\u2022") if bullet else ("number", f"{m.group(2)}.")
    return Block(kind, inline(" ".join(text)), level=indent // 2, marker=marker), i


def parse(markdown: str) -> list[Block]:
    """Blocks of a Markdown page, in order."""
    lines = markdown.splitlines()
    blocks: list[Block] = []
    i = 0
    para: list[str] = []

    def flush_para() -> None:
        if para:
            blocks.append(Block("para", inline(" ".join(t.strip() for t in para))))
            para.clear()

    while i < len(lines):
        raw = lines[i]
        t = raw.rstrip()
        if not t.strip():
            flush_para()
            if blocks and blocks[-1].kind != "blank":
                blocks.append(Block("blank"))
            i += 1
            continue
        if t.lstrip().startswith("```"):
            flush_para()
            code = []
            i += 1
            while i < len(lines) and not lines[i].lstrip().startswith("```"):
                code.append(lines[i].rstrip())
                i += 1
            blocks.append(Block("code", text="\n".join(code)))
            i += 1
            continue
        if t.startswith("    ") and not para:
            code = []
            while i < len(lines) and (lines[i].startswith("    ") or not lines[i].strip()):
                code.append(lines[i][4:].rstrip())
                i += 1
            while code and not code[-1]:
                code.pop()
            blocks.append(Block("code", text="\n".join(code)))
            continue
        if t.startswith("#"):
            flush_para()
            level = len(t) - len(t.lstrip("#"))
            blocks.append(Block("heading", inline(t.lstrip("#").strip()), level=min(level, 3)))
            i += 1
            continue
        if t.lstrip().startswith("|") and i + 1 < len(lines) and _SEP.match(lines[i + 1]):
            flush_para()
            block, i = _table_at(lines, i)
            blocks.append(block)
            continue
        mb, mn = _BULLET.match(t), _NUMBER.match(t)
        m = mb or mn
        if m is not None:
            flush_para()
            block, i = _item_at(lines, i, m, bullet=mb is not None)
            blocks.append(block)
            continue
        para.append(t)
        i += 1
    flush_para()
    while blocks and blocks[-1].kind == "blank":
        blocks.pop()
    return blocks


# -- layout ---------------------------------------------------------------------------------------


def _words(spans: list[Span]) -> list[tuple[str, str, bool]]:
    """(text, style, space_before) for every word of the spans."""
    out = []
    space = False
    for sp in spans:
        parts = re.split(r"(\s+)", sp.text)
        for p in parts:
            if not p:
                continue
            if p.isspace():
                space = True
                continue
            out.append((p, sp.style, space))
            space = False
    return out


def wrap_spans(spans: list[Span], width: float, measure: Measure) -> list[list[Run]]:
    """Greedy word wrap of styled spans to `width` pixels; a word wider than a line is cut."""
    lines: list[list[Run]] = [[]]
    x = 0.0
    space_w = measure(" ", "body")
    for word, style, space in _words(spans):
        w = measure(word, style)
        gap = space_w if (space and lines[-1]) else 0.0
        if lines[-1] and x + gap + w > width:
            lines.append([])
            x, gap = 0.0, 0.0
        while w > width and len(word) > 1:  # a long word (a path, a formula) is split over lines
            cut = len(word)
            while cut > 1 and measure(word[:cut], style) > width - x:
                cut -= 1
            lines[-1].append(Run(x, word[:cut], style))
            lines.append([])
            word, x = word[cut:], 0.0
            w = measure(word, style)
        prev = lines[-1][-1] if lines[-1] else None
        if prev is not None and prev.style == style:
            prev.text += (" " if gap else "") + word
        else:
            lines[-1].append(Run(x + gap, word, style))
        x += gap + w
    return lines


def _table(block: Block, width: float, measure: Measure, line_h: float, pad: float) -> list[Line]:
    rows = block.rows
    ncol = max(len(r) for r in rows)
    rows = [r + [[] for _ in range(ncol - len(r))] for r in rows]
    natural = [0.0] * ncol
    for k, r in enumerate(rows):
        for c, cell in enumerate(r):
            # the header row is drawn bold (wider): measure it so, or a short header is cut mid-word
            styles = ["bold" if k == 0 and sp.style == "body" else sp.style for sp in cell]
            natural[c] = max(natural[c], sum(measure(sp.text, st) for sp, st in zip(cell, styles)) + 2 * pad)
    widths = list(natural)
    if sum(widths) > width:
        # water-filling: columns narrower than a fair share keep their width, the rest share what is left
        fixed: dict[int, float] = {}
        while True:
            free = [c for c in range(ncol) if c not in fixed]
            share = (width - sum(fixed.values())) / max(len(free), 1)
            small = [c for c in free if natural[c] <= share]
            if not small:
                break
            for c in small:
                fixed[c] = natural[c]
        widths = [fixed.get(c, share) for c in range(ncol)]
    out = []
    for k, r in enumerate(rows):
        wrapped = []
        for c, cell in enumerate(r):
            spans = [Span(sp.text, "bold" if k == 0 and sp.style == "body" else sp.style) for sp in cell]
            wrapped.append(wrap_spans(spans, max(widths[c] - 2 * pad, 10.0), measure))
        n = max(len(w) for w in wrapped)
        xs = [sum(widths[:c]) for c in range(ncol)]
        for j in range(n):
            runs = []
            for c in range(ncol):
                if j < len(wrapped[c]):
                    runs += [Run(xs[c] + pad + ru.x, ru.text, ru.style) for ru in wrapped[c][j]]
            boxes = [(xs[c], widths[c], "head" if k == 0 else "cell") for c in range(ncol)]
            out.append(Line(line_h, runs, boxes, grid=(j == n - 1)))
    return out


def layout(blocks: list[Block], width: float, measure: Measure, line_h: Callable[[str], float]) -> list[Line]:
    """Lines of the page at `width` pixels; `line_h(style)` is the height of a line in that style."""
    body = line_h("body")
    indent_w = measure("\u2022  ", "body")
    out: list[Line] = []
    for k, b in enumerate(blocks):
        if b.kind == "blank":
            out.append(Line(body * 0.5))
        elif b.kind == "heading":
            style = f"h{b.level}"
            spans = [Span(sp.text, style) for sp in b.spans]
            for runs in wrap_spans(spans, width, measure):
                out.append(Line(line_h(style), runs, style=style))
        elif b.kind == "para":
            for runs in wrap_spans(b.spans, width, measure):
                out.append(Line(body, runs))
        elif b.kind in ("bullet", "number"):
            left = indent_w * (b.level + 1) + (measure(b.marker, "body") - measure("\u2022", "body"))
            wrapped = wrap_spans(b.spans, width - left, measure)
            for j, runs in enumerate(wrapped):
                shifted = [Run(r.x + left, r.text, r.style) for r in runs]
                if j == 0:
                    shifted.insert(0, Run(indent_w * b.level, b.marker, "body"))
                out.append(Line(body, shifted))
        elif b.kind == "code":
            for t in b.text.split("\n"):
                out.append(Line(body, [Run(16.0, t, "code")] if t else []))
            if k + 1 < len(blocks) and blocks[k + 1].kind != "blank":  # a paragraph right after: a gap
                out.append(Line(body * 0.5))
        elif b.kind == "table":
            out += _table(b, width, measure, body, 6.0)
    return out


def plain(markdown: str) -> str:
    """The page's text without Markdown marks (tests, terminals)."""
    out = []
    for b in parse(markdown):
        if b.kind == "table":
            out += [" | ".join("".join(s.text for s in cell) for cell in row) for row in b.rows]
        elif b.kind == "code":
            out.append(b.text)
        elif b.kind == "blank":
            out.append("")
        else:
            out.append((b.marker + " " if b.marker else "") + "".join(s.text for s in b.spans))
    return "\n".join(out)

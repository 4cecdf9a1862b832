"""Drawing a page box: a docs page or the key overlay, laid out by chainsim.systems.view.ui.markdown.

Headings are larger and accent-coloured, bold is drawn twice a pixel apart, italic leans, code is
tinted, tables get a shaded header row and a grid. The box geometry (and the footer buttons the view
system hit-tests) comes from chainsim.systems.view.ui.docbox. Layouts are cached per text and width, so
an open page costs only its glyph quads per frame.
"""

from __future__ import annotations

from chainsim.game.render.overlay import Overlay
from chainsim.systems.view.ui import docbox
from chainsim.systems.view.ui import markdown as md
from chainsim.systems.view.ui.viewports import Rect

BOX_BG = (0.03, 0.035, 0.05, 0.96)
TEXT = (0.92, 0.93, 0.95, 1.0)
BOLD = (1.0, 1.0, 1.0, 1.0)
ITALIC = (0.80, 0.84, 0.92, 1.0)
CODE = (0.72, 0.86, 1.0, 1.0)
ACCENT = (0.30, 0.62, 0.95, 1.0)
DIM = (0.6, 0.65, 0.75, 1.0)
HEAD_BG = (0.15, 0.19, 0.27, 1.0)
GRID = (0.36, 0.40, 0.50, 1.0)
BUTTON = (0.25, 0.33, 0.45, 1.0)
BUTTON_OFF = (0.16, 0.17, 0.21, 1.0)
HEADING_SCALE = {"h1": 1.4, "h2": 1.2, "h3": 1.05}


class PageView:
    """Lays out and draws pages; keeps the last layouts so scrolling does not lay out again."""

    def __init__(self, overlay: Overlay):
        self.ov = overlay
        self._cache: dict[tuple, list[md.Line]] = {}

    def font(self, style: str):
        ov = self.ov
        k = HEADING_SCALE.get(style)
        return ov.font if k is None else ov.font_sized(ov.font_px_base * k)

    def measure(self, text: str, style: str) -> float:
        w = self.font(style).width(text)
        return w + 1.0 if style in ("bold", "bolditalic", "h1", "h2", "h3") else w

    def line_h(self, style: str) -> float:
        f = self.font(style)
        return f.line_h * (1.35 if style in HEADING_SCALE else 1.0)

    def lines(self, text: str, width: float) -> list[md.Line]:
        key = (text, round(width), self.ov.scale)
        got = self._cache.get(key)
        if got is None:
            if len(self._cache) > 16:
                self._cache.clear()
            got = self._cache[key] = md.layout(md.parse(text), width, self.measure, self.line_h)
        return got

    def fit(self, lines: list[md.Line], first: int, height: float) -> int:
        """How many lines from `first` fit in `height` pixels."""
        used, n = 0.0, 0
        for ln in lines[first:]:
            if used + ln.height > height:
                break
            used += ln.height
            n += 1
        return n

    def max_first(self, lines: list[md.Line], height: float) -> int:
        """The first line index that shows the end of the page."""
        used, k = 0.0, len(lines)
        while k > 0 and used + lines[k - 1].height <= height:
            used += lines[k - 1].height
            k -= 1
        return k

    def draw(
        self, box: Rect, s: float, title: str, text: str, first: int, buttons: dict[str, bool] | None = None
    ) -> tuple[int, int]:
        """Draw the page in `box` (window units) scrolled to line `first`; returns (first used, last first).

        `buttons`: footer button name -> enabled (None: no footer)."""
        ov = self.ov
        b = box.scaled(s)
        area = docbox.text_area(box).scaled(s)
        ov.rect(b.x, b.y, b.w, b.h, BOX_BG)
        ov.frame(b.x, b.y, b.w, b.h, ACCENT, s)
        tf = self.font("h3")
        if title and not text.lstrip().startswith("#"):  # a page that opens with a heading titles itself
            ov.label(title, area.x, b.y + b.h - 10 * s - tf.ascent, ACCENT, max_w=area.w, font=tf, bold=True)
        lines = self.lines(text, area.w)
        last_first = self.max_first(lines, area.h)
        first = max(0, min(first, last_first))
        n = self.fit(lines, first, area.h)
        y = area.y + area.h
        prev_table = first > 0 and bool(lines[first - 1].boxes)
        for ln in lines[first : first + n]:
            y -= ln.height
            self._line(ln, area.x, y, s, top_rule=bool(ln.boxes) and not prev_table)
            prev_table = bool(ln.boxes)
        if len(lines) > n:  # scroll bar: where the shown part lies in the page
            total = sum(ln.height for ln in lines)
            above = sum(ln.height for ln in lines[:first])
            shown = sum(ln.height for ln in lines[first : first + n])
            bx = area.x + area.w + 4 * s
            ov.rect(bx, area.y, docbox.SCROLLBAR_W * s, area.h, (0.12, 0.13, 0.17, 1.0))
            h = max(area.h * shown / total, 12 * s)
            top = area.y + area.h - (area.h - h) * (above / max(total - shown, 1e-9))
            ov.rect(bx, top - h, docbox.SCROLLBAR_W * s, h, DIM)
        if buttons is not None:
            for name, r in docbox.buttons(box, tuple(buttons)).items():
                rr = r.scaled(s)
                on = buttons[name]
                ov.rect(rr.x, rr.y, rr.w, rr.h, BUTTON if on else BUTTON_OFF)
                label = docbox.PAGE_BUTTON_LABELS.get(name, name)
                f = ov.font
                ov.label(
                    label,
                    rr.x + max((rr.w - f.width(label)) / 2, 4 * s),
                    rr.y + (rr.h - f.ascent) / 2 + 1,
                    TEXT if on else DIM,
                    max_w=rr.w - 8 * s,
                )
        if len(lines) > n:  # top right, in the title row
            more = f"lines {first + 1}-{first + n} of {len(lines)}: PageUp / PageDown or the wheel"
            f = ov.font
            ov.label(more, b.x + b.w - f.width(more) - 14 * s, b.y + b.h - 10 * s - f.ascent, DIM)
        return first, last_first

    def _line(self, ln: md.Line, x0: float, y: float, s: float, top_rule: bool) -> None:
        ov = self.ov
        if ln.boxes:
            for bx, bw, kind in ln.boxes:
                if kind == "head":
                    ov.rect(x0 + bx * 1.0, y, bw, ln.height, HEAD_BG)
                ov.rect(x0 + bx, y, 1.0 * s, ln.height, GRID)
            last = ln.boxes[-1]
            ov.rect(x0 + last[0] + last[1] - s, y, 1.0 * s, ln.height, GRID)
            right = last[0] + last[1]
            if ln.grid:
                ov.rect(x0, y, right, 1.0 * s, GRID)
            if top_rule:
                ov.rect(x0, y + ln.height - s, right, 1.0 * s, GRID)
        for run in ln.runs:
            style = run.style
            f = self.font(style)
            base = y + (ln.height - f.line_h) / 2 + f.descent + 1
            if run.text == "\u2022":  # a list bullet: a dot of its own (the bundled font has no glyph)
                ov.disc(x0 + run.x + f.width("x") / 2, base + f.ascent * 0.35, max(2.0 * s, f.ascent * 0.16), TEXT, 12)
                continue
            color = {
                "bold": BOLD,
                "italic": ITALIC,
                "bolditalic": BOLD,
                "code": CODE,
                "h1": ACCENT,
                "h2": ACCENT,
                "h3": BOLD,
            }.get(style, TEXT)
            ov.label(
                run.text,
                x0 + run.x,
                base,
                color,
                font=f,
                bold=style in ("bold", "bolditalic", "h1", "h2", "h3"),
                slant=0.18 if style in ("italic", "bolditalic") else 0.0,
            )

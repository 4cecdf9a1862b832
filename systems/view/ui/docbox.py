"""Where the page box (docs pages, the key overlay, sign-in and questions) sits, without GL.

One box at a time is open over the main 3-D view, never over the control panel, so the controller
stays usable while a page is read (thesis 3.4: the documentation is part of the trainer). The box
leaves room at the top of the view for the step text and messages. The same rectangles serve the
renderer (what to draw where) and the view system (which clicks and wheel turns the box takes), so
a click on a page button never reaches the face underneath.

All rectangles are in window units, origin bottom-left (chainsim.systems.view.ui.viewports.Rect).
"""

from __future__ import annotations

from chainsim.systems.view.ui.viewports import Rect

MARGIN = 16  # between the box and the view's edges
TOP_ROOM = 116  # above the box: the view title, the step title and instruction, two messages
MAX_W = 800
FOOTER = 34  # the row of page buttons along the bottom
BUTTON_W = 150
BUTTON_H = 24
SCROLLBAR_W = 8

#: page buttons along the bottom of a docs page, left to right
PAGE_BUTTONS = ("prev", "next", "close")
#: the key page's: on to the pack's help pages, and close
KEY_PAGE_BUTTONS = ("docs", "close")
PAGE_BUTTON_LABELS = {"prev": "< Previous page", "next": "Next page >", "docs": "Help pages >", "close": "Close [Esc]"}


def box(view: Rect) -> Rect:
    """The page box inside the main view `view`."""
    w = max(min(view.w - 2 * MARGIN, MAX_W), 40)
    h = max(view.h - MARGIN - TOP_ROOM, 60)
    return Rect(view.x + MARGIN, view.y + MARGIN, w, h)


def text_area(b: Rect) -> Rect:
    """Where the page's lines go: under the title row, above the footer, left of the scroll bar."""
    pad = 14
    title = 30
    return Rect(b.x + pad, b.y + FOOTER + 6, b.w - 2 * pad - SCROLLBAR_W - 4, b.h - FOOTER - 6 - title)


def buttons(b: Rect, names=PAGE_BUTTONS) -> dict[str, Rect]:
    """The footer buttons of box `b`: previous and next page on the left, close on the right."""
    y = b.y + (FOOTER - BUTTON_H) // 2 + 2
    out = {}
    x = b.x + 14
    for n in names:
        if n == "close":
            out[n] = Rect(b.x + b.w - 14 - BUTTON_W, y, BUTTON_W, BUTTON_H)
        else:
            out[n] = Rect(x, y, BUTTON_W, BUTTON_H)
            x += BUTTON_W + 10
    return out


def button_at(b: Rect, x: float, y: float, names=PAGE_BUTTONS) -> str | None:
    for n, r in buttons(b, names).items():
        if r.contains(x, y):
            return n
    return None

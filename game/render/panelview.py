"""Drawing the 2-D parts of a frame in window pixels: view captions, 3-D labels, the HUD, the aiming
aid of an attached view, and the control panel with its widgets (thesis 3.3.4 controller).

Widget placement and values come from chainsim.systems.view.ui.widgets (no GL); this module only turns
them into Overlay shapes and text. Numbers are shown with `widgets.format_value`, one format for
every dial, slider and text.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from chainsim.game.render.overlay import Font, Overlay
from chainsim.systems.view.ui import docbox
from chainsim.systems.view.ui.viewports import Rect
from chainsim.systems.view.ui.widgets import TITLE_PX, below_widgets, format_value

PANEL_BG = (0.13, 0.14, 0.17, 1.0)
TEXT = (0.92, 0.93, 0.95, 1.0)
DIM = (0.55, 0.57, 0.62, 1.0)
ACCENT = (0.30, 0.62, 0.95, 1.0)
MESSAGE = (1.0, 0.85, 0.3, 1.0)
AIM = (0.35, 1.0, 0.45, 1.0)
CROSS = (1.0, 1.0, 1.0, 0.85)
LIGHT_RGBA = {"red": (0.92, 0.18, 0.16, 1.0), "green": (0.20, 0.85, 0.30, 1.0), "off": (0.30, 0.30, 0.32, 1.0)}


def view_title(ov: Overlay, title: str, r: Rect, s: float) -> None:
    f = ov.font
    w = f.width(title) + 12 * s
    # dark enough to read over a bright view (the needle-tip view is often filled by bone)
    ov.rect(r.x, r.y + r.h - f.line_h - 6 * s, w, f.line_h + 6 * s, (0, 0, 0, 0.7))
    ov.label(title, r.x + 6 * s, r.y + r.h - f.ascent - 3 * s, TEXT)


#: a button's label is drawn down to this share of the font's size before it is cut short
BUTTON_FONT_MIN = 0.65


def button_label(ov: Overlay, f, label: str, key: str, room: float):
    """(text, font) of a button `room` pixels wide: the label with its key, else the label alone, else
    (a narrow window: 1024 x 768) the label in a smaller font, down to BUTTON_FONT_MIN of `f` (only a
    label wider still is cut short, with an ellipsis)."""
    text = label + key
    if f.width(text) > room:
        text = label
    if f.width(text) > room:
        f = ov.font_sized(max(int(f.font.size * room / f.width(text)), BUTTON_FONT_MIN * f.font.size))
    return text, f


def window_level_text(window: float, level: float) -> str:
    """The monitor's window/level as the C-arm view shows it ('' while at the automatic setting)."""
    if window == 1.0 and level == 0.0:
        return ""
    return f"W x{window:.2f}  L {level:+.2f}  (right-click: reset)"


#: what the C-arm view says between the shot and its image (chainsim.game.render.radiograph: the window's cue)
TAKING = "Taking X-ray..."


def fluoro_status(
    ov: Overlay,
    status: str,
    live: bool,
    has_image: bool,
    r: Rect,
    s: float,
    window_level: str = "",
    taking: bool = False,
) -> None:
    """The C-arm view's lines: what the image is and costs along the bottom, LIVE while the pedal is held,
    the monitor's window/level once turned from automatic (with how to reset it), how to make the
    first image before there is one, and (`taking`) that an image is being made."""
    f = ov.font
    if taking:
        w = min(f.width(TAKING) + 24 * s, r.w - 8 * s)
        h = f.line_h + 12 * s
        x, y = r.x + (r.w - w) / 2, r.y + (r.h - h) / 2
        ov.rect(x, y, w, h, (0.0, 0.0, 0.0, 0.75))
        ov.label(TAKING, x + 12 * s, y + 6 * s + f.descent, MESSAGE, max_w=w - 16 * s)
    if window_level and has_image:
        w = min(f.width(window_level) + 12 * s, r.w - 8 * s)
        y = r.y + r.h - 2 * f.line_h - 14 * s  # under the view's title and LIVE
        ov.rect(r.x + r.w - w - 4 * s, y - 2 * s, w, f.line_h + 4 * s, (0, 0, 0, 0.55))
        ov.label(window_level, r.x + r.w - w + 2 * s, y + f.descent, TEXT, max_w=w - 8 * s)
    if not has_image and not taking:
        msg = "No image yet: Take X-ray (x)"
        ov.label(msg, r.x + max((r.w - f.width(msg)) / 2, 4 * s), r.y + r.h / 2, DIM, max_w=r.w - 8 * s)
    if status:
        ov.rect(r.x, r.y, r.w, f.line_h + 4 * s, (0, 0, 0, 0.55))
        ov.label(status, r.x + 6 * s, r.y + 2 * s + f.descent, TEXT, max_w=r.w - 12 * s)
    if live:
        w = f.width("LIVE") + 10 * s
        ov.rect(r.x + r.w - w - 6 * s, r.y + r.h - f.line_h - 8 * s, w, f.line_h + 2 * s, (0.8, 0.1, 0.1, 0.9))
        ov.label("LIVE", r.x + r.w - w - 1 * s, r.y + r.h - f.ascent - 6 * s, TEXT)


DEBRIEF_TONES = {
    "head": (0.45, 0.95, 0.55, 1.0),
    "critical": (1.0, 0.42, 0.38, 1.0),
    "pass": (0.55, 0.95, 0.60, 1.0),
    "fail": (1.0, 0.55, 0.50, 1.0),
    "plain": TEXT,
    "note": TEXT,
    "advice": MESSAGE,
}
#: the debrief box takes at most this share of the main view's height (the head stays in sight above it)
DEBRIEF_SHARE = 0.5


def debrief_layout(
    f, rows: list[tuple[str, str]], width: float, columns: bool = True
) -> list[list[tuple[str, str, float]]] | None:
    """Lines of (text, tone, x offset): metric rows two to a line (None when one does not fit half the
    width), or with `columns` false one to a line; every other row wrapped to the whole width."""
    col = (width - 12) / 2
    metric = [t for t, tone in rows[1:] if tone in ("pass", "fail", "plain")]
    two = columns and bool(metric)
    if two and not all(f.width(t) <= col for t in metric):
        return None
    lines: list[list[tuple[str, str, float]]] = []
    pending: list[tuple[str, str, float]] = []
    for i, (text, tone) in enumerate(rows):
        if two and i > 0 and tone in ("pass", "fail", "plain"):
            pending.append((text, tone, 0.0 if not pending else col + 12))
            if len(pending) == 2:
                lines.append(pending)
                pending = []
            continue
        if pending:
            lines.append(pending)
            pending = []
        lines += [[(t, tone, 0.0)] for t in f.wrap(text, width)]
    if pending:
        lines.append(pending)
    return lines


@dataclass
class DebriefFit:
    """Where the debrief goes: its font, its lines of (text, tone, x offset) and its box in window
    pixels; `max_w(dx)` is the width a line starting at dx may take (text wider than that is cut)."""

    font: Font
    lines: list[list[tuple[str, str, float]]]
    x: float
    y: float
    w: float
    h: float
    pad: float

    def max_w(self, dx: float) -> float:
        return self.w - 2 * self.pad - dx


def debrief_fit(ov: Overlay, rows: list[tuple[str, str]], r: Rect, s: float) -> DebriefFit:
    """The debrief's layout in a box along the bottom of the main view, in the largest font (down to
    0.7 of the main one) whose lines all fit in DEBRIEF_SHARE of the view's height; where none does,
    the smallest font in one column (every line still inside the view: the box grows upwards)."""
    pad = 8 * s
    w = r.w - 2 * pad
    base = ov.font_px_base
    # two columns in the largest font that fits, else one column; the head stays in sight above the box
    tries = [(k, c) for c in (True, False) for k in (1.0, 0.92, 0.84, 0.76, 0.7)]
    for k, c in tries:
        f = ov.font_sized(base * k)
        lines = debrief_layout(f, rows, w - 2 * pad, c)
        if lines is None:
            continue
        bh = len(lines) * f.line_h + pad
        if bh <= r.h * DEBRIEF_SHARE:
            break
    assert lines is not None  # the last try, one column, always lays out
    return DebriefFit(f, lines, r.x + pad, r.y + pad, w, min(bh, r.h - 2 * pad), pad)


def debrief(ov: Overlay, rows: list[tuple[str, str]], r: Rect, s: float) -> DebriefFit:
    """The attempt's debrief drawn where debrief_fit puts it; returns that layout."""
    fit = debrief_fit(ov, rows, r, s)
    f, pad = fit.font, fit.pad
    ov.rect(fit.x, fit.y, fit.w, fit.h, (0.0, 0.0, 0.0, 0.78))
    top = fit.y + fit.h - pad / 2
    for i, line in enumerate(fit.lines):
        for text, tone, dx in line:
            ov.label(
                text,
                fit.x + pad + dx,
                top - (i + 1) * f.line_h + f.descent,
                DEBRIEF_TONES.get(tone, TEXT),
                max_w=fit.max_w(dx),
                font=f,
                bold=tone in ("head", "critical"),
            )
    return fit


#: the force chart over the debrief: its size in window pixels (times the scale)
FORCE_CHART = (300.0, 130.0)


def force_chart(ov: Overlay, points: list[tuple], r: Rect, fit: DebriefFit, s: float) -> None:
    """The force the hand felt through the device against the needle's depth (in and out), each puncture
    a red mark where the layer gave, in a box at the right end of the main view just above the debrief."""
    w, h = FORCE_CHART[0] * s, FORCE_CHART[1] * s
    x0, y0 = r.x + r.w - w - 8 * s, min(fit.y + fit.h + 6 * s, r.y + r.h - h - 8 * s)
    f = ov.font_sized(ov.font_px_base * 0.85)
    ov.rect(x0, y0, w, h, (0.0, 0.0, 0.0, 0.78))
    depth = [float(p[0]) for p in points]
    force = [float(p[1]) for p in points]
    lo_d, hi_d = min(depth + [0.0]), max(depth + [1.0])
    hi_f = max(force + [0.5])
    lo_f = min(force + [0.0])
    px, py, pw, ph = x0 + 36 * s, y0 + f.line_h + 8 * s, w - 44 * s, h - 2 * f.line_h - 14 * s

    def at(d: float, fn: float) -> tuple[float, float]:
        return px + (d - lo_d) / (hi_d - lo_d) * pw, py + (fn - lo_f) / (hi_f - lo_f) * ph

    ov.segment(*at(lo_d, 0.0), *at(hi_d, 0.0), (0.5, 0.5, 0.5, 1.0), s)
    for a, b in zip(points, points[1:], strict=False):
        ov.segment(*at(float(a[0]), float(a[1])), *at(float(b[0]), float(b[1])), (0.45, 0.7, 1.0, 1.0), 1.5 * s)
    for k, p in enumerate(points):
        if int(p[2]) & 1:  # a puncture: marked where the layer gave, the point before the force dropped
            q = points[max(k - 1, 0)]
            ov.disc(*at(float(q[0]), float(q[1])), 3.5 * s, (1.0, 0.35, 0.3, 1.0))
    ov.label("Force felt through the device", x0 + 6 * s, y0 + h - f.ascent - 4 * s, TEXT, font=f)
    ov.label(f"{hi_f:.1f} N", x0 + 4 * s, py + ph - f.ascent, DIM, font=f)
    ov.label("0", x0 + 4 * s, at(lo_d, 0.0)[1] - f.ascent / 2, DIM, font=f)
    ov.label(f"depth {lo_d:.0f}-{hi_d:.0f} mm; red: a layer gave", px, y0 + 4 * s + f.descent, DIM, font=f, max_w=pw)


def debrief_paths(ov: Overlay, camera, r: Rect, paths: list[tuple], s: float, square: bool = False) -> None:
    """The debrief's ideal path and the trainee's, projected with a view's camera and drawn over it
    (in front of skin and bone, which would hide them inside the head). `square`: the X-ray image,
    drawn square and centred in its view."""
    side = min(r.w, r.h)
    sq = Rect(r.x + (r.w - side) // 2, r.y + (r.h - side) // 2, side, side) if square else r
    for pts, color in paths:
        p = camera.project(np.asarray(pts, float).reshape(-1, 3), sq)
        for a, b in zip(p[:-1], p[1:], strict=True):
            if -1 < a[2] < 1 and -1 < b[2] < 1:
                ov.segment(a[0], a[1], b[0], b[1], color, 2.5 * s)


def hud(ov: Overlay, h, r: Rect, s: float) -> None:
    """Step title, instruction and messages in a dark band at the top of the main view; the debrief,
    while shown, along its bottom."""
    if getattr(h, "debrief", None):
        fit = debrief(ov, h.debrief, r, s)
        if getattr(h, "debrief_force", None):
            force_chart(ov, h.debrief_force, r, fit, s)
    f = ov.font
    pad = 8 * s
    width = min(r.w - 2 * pad, 640 * s)
    head = []
    if h.step_title:
        head.append((h.step_title, ACCENT))
    if h.step_instruction:
        head += [(t, TEXT) for t in f.wrap(h.step_instruction, width - 2 * pad)]
    said = [[(t, MESSAGE) for t in f.wrap(text, width - 2 * pad)] for text in h.shown_messages()[-3:]]
    top = r.y + r.h - f.line_h - 14 * s  # under the viewport title
    if h.doc_open or h.notice:
        # a page is open below (chainsim.systems.view.ui.docbox): the band ends above its top edge, so the
        # oldest messages give way first, then the instruction's last lines
        room = max(int((top - (r.y + r.h - docbox.TOP_ROOM * s) - pad - 2 * s) // f.line_h), 1)
        while said and len(head) + sum(map(len, said)) > room and len(said) > 1:
            said.pop(0)
        keep = max(room - sum(map(len, said)), 1)
        if len(head) > keep:
            head = head[: keep - 1] + [(head[keep - 1][0] + " ...", head[keep - 1][1])]
        said = [m[: max(room - len(head), 0)] for m in said]
    lines = head + [ln for m in said for ln in m]
    if not lines:
        return
    bh = len(lines) * f.line_h + pad
    x0 = r.x + pad
    ov.rect(x0, top - bh, width, bh, (0.0, 0.0, 0.0, 0.55))
    for i, (t, c) in enumerate(lines):
        ov.label(t, x0 + pad, top - (i + 1) * f.line_h + f.descent, c, max_w=width - 2 * pad)


def aim(ov: Overlay, camera, r: Rect, target, note: str, s: float) -> None:
    """Crosshair at the centre of an attached view (where the needle points) and the target's
    projected position: a ring with its distance, or an arrow at the edge when it is out of view.
    Without a target (fluoroscopy first) only the crosshair and `note`, at the foot of the view."""
    cx, cy = r.x + r.w / 2, r.y + r.h / 2
    arm, gap = 14 * s, 4 * s
    for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        ov.segment(cx + dx * gap, cy + dy * gap, cx + dx * arm, cy + dy * arm, CROSS, 1.5 * s)
    if target is None or camera is None:
        if note:
            f = ov.font
            backed_label(ov, note, r.x + max((r.w - f.width(note)) / 2, 4 * s), r.y + 6 * s + f.descent, TEXT, s)
        return
    eye = np.asarray(camera.eye, float)
    ahead = float((np.asarray(target, float) - eye) @ camera.forward)
    x, y, _z = camera.project(target, r)[0]
    f = ov.font
    inside = ahead > 0 and r.x + 6 * s <= x <= r.x + r.w - 6 * s and r.y + 6 * s <= y <= r.y + r.h - 6 * s
    if inside:
        ring(ov, x, y, 9 * s, AIM, 2 * s)
        # above and right of the ring, its box clear of the crosshair's arm when the ring is centred
        backed_label(ov, note, min(x + 12 * s, r.x + r.w - f.width(note) - 4 * s), y + 8 * s + f.descent, AIM, s)
        return
    # out of view (or behind): an arrow on the edge pointing the way to turn
    dx, dy = (x - cx, y - cy) if ahead > 0 else (cx - x, cy - y)
    n = math.hypot(dx, dy) or 1.0
    dx, dy = dx / n, dy / n
    k = min((r.w / 2 - 18 * s) / max(abs(dx), 1e-6), (r.h / 2 - 18 * s) / max(abs(dy), 1e-6))
    ex, ey = cx + dx * k, cy + dy * k
    tail = 16 * s
    ov.segment(ex - dx * tail, ey - dy * tail, ex, ey, AIM, 3 * s)
    px, py = -dy, dx
    ov.segment(ex, ey, ex - dx * 8 * s + px * 6 * s, ey - dy * 8 * s + py * 6 * s, AIM, 3 * s)
    ov.segment(ex, ey, ex - dx * 8 * s - px * 6 * s, ey - dy * 8 * s - py * 6 * s, AIM, 3 * s)
    text = f"target {note}" if ahead > 0 else f"target behind, {note}"
    tx = min(max(ex - f.width(text) / 2, r.x + 4 * s), r.x + r.w - f.width(text) - 4 * s)
    ty = min(max(ey - dy * 30 * s, r.y + 6 * s), r.y + r.h - 2 * f.line_h)
    backed_label(ov, text, tx, ty, AIM, s)


#: the force gauge's bar: green below half scale, yellow, red near full scale
GAUGE_COLOURS = ((0.35, 0.85, 0.45, 0.95), (0.95, 0.8, 0.2, 0.95), (0.95, 0.3, 0.25, 0.95))


def force_gauge(ov: Overlay, r: Rect, gauge: tuple, s: float) -> None:
    """The needle's axial force as a bar along the foot of the view (green, yellow past half scale, red
    near it), its figures and layer above, and the pop of a layer giving way in large letters."""
    axial, lateral, full, caption, pop = gauge
    f = ov.font
    x0, y0 = r.x + 8 * s, r.y + 8 * s
    w, h = r.w * 0.6, 9 * s
    frac = min(max(axial / full, 0.0), 1.0) if full > 0 else 0.0
    colour = GAUGE_COLOURS[0] if frac < 0.5 else GAUGE_COLOURS[1] if frac < 0.85 else GAUGE_COLOURS[2]
    ov.rect(x0 - 2 * s, y0 - 2 * s, w + 4 * s, h + 4 * s, (0.0, 0.0, 0.0, 0.6))
    ov.rect(x0, y0, w * frac, h, colour)
    text = f"{axial:.2f} N axial, {lateral:.2f} N lateral" + (f", {caption}" if caption else "")
    backed_label(ov, text, x0, y0 + h + 6 * s + f.descent, TEXT, s)
    if pop:
        backed_label(ov, pop, x0, y0 + h + 8 * s + f.line_h + f.descent, (1.0, 0.85, 0.3, 1.0), s)


def backed_label(ov: Overlay, text: str, x: float, baseline: float, color, s: float) -> None:
    """A label on a dark box, readable over bright bone or a see-through head as over the background."""
    f = ov.font
    ov.rect(x - 3 * s, baseline - f.descent - 2 * s, f.width(text) + 6 * s, f.line_h + 2 * s, (0, 0, 0, 0.6))
    ov.label(text, x, baseline, color)


def ring(ov: Overlay, cx: float, cy: float, radius: float, color, width: float, segments: int = 24) -> None:
    for i in range(segments):
        a0, a1 = 2 * math.pi * i / segments, 2 * math.pi * (i + 1) / segments
        ov.segment(
            cx + radius * math.cos(a0),
            cy + radius * math.sin(a0),
            cx + radius * math.cos(a1),
            cy + radius * math.sin(a1),
            color,
            width,
        )


def panel(ov: Overlay, p, h, s: float) -> None:
    """A control panel: caption, widgets, lights without a widget, panel text, status and hint."""
    f = ov.font
    r = p.rect.scaled(s)
    ov.rect(r.x, r.y + r.h - TITLE_PX * s, r.w, TITLE_PX * s, (0.18, 0.20, 0.25, 1.0))
    ov.label(
        p.title or p.name,
        r.x + 8 * s,
        r.y + r.h - TITLE_PX * s + (TITLE_PX * s - f.ascent) / 2,
        TEXT,
        max_w=r.w - 16 * s,
    )
    lights = dict(h.lights) if h is not None else {}
    shown = set()
    for pl in p.placed:
        widget(ov, pl, p, lights, s)
        shown.add(pl.spec["name"])
    y = below_widgets(p.placed, p.rect) * s
    # the status line gives way to panel text (an assessment needs the room)
    status = f.wrap(h.status, r.w - 16 * s) if h is not None and h.status and not h.panel_text else []
    hint = f.wrap(p.hint, r.w - 16 * s) if p.hint else []
    bottom = hint or status  # the hint of the widget under the pointer replaces the status line
    floor = r.y + (len(bottom) * f.line_h + 8 * s if bottom else 0)
    for name, state in [(n, v) for n, v in lights.items() if n not in shown]:
        y -= 22 * s
        if y < floor:
            break
        ov.disc(r.x + 18 * s, y + 8 * s, 7 * s, LIGHT_RGBA.get(state, LIGHT_RGBA["off"]))
        ov.label(name, r.x + 32 * s, y + 3 * s, TEXT, max_w=r.w - 40 * s)
    if h is not None and h.panel_text:
        y -= 6 * s
        for t in [t for line in h.panel_text for t in f.wrap(line, r.w - 16 * s)]:
            y -= f.line_h
            if y < floor:
                break
            ov.label(t, r.x + 8 * s, y + f.descent, TEXT)
    if bottom:
        ov.rect(r.x, r.y, r.w, floor - r.y, (0.08, 0.09, 0.11, 1.0))
        for i, t in enumerate(reversed(bottom)):
            ov.label(t, r.x + 8 * s, r.y + 4 * s + i * f.line_h + f.descent, DIM if hint else TEXT)


def widget(ov: Overlay, pl, p, lights: dict, s: float) -> None:
    spec = pl.spec
    name, kind = spec["name"], spec["kind"]
    r = pl.rect.scaled(s)
    f = ov.font_for(r.h / 2 if kind in ("slider", "dial") else r.h)  # short widgets get a smaller font
    value = p.values.get(name)
    off = name in p.disabled
    fg = DIM if off else TEXT
    label = spec.get("label") or name
    key = f" [{spec['key']}]" if spec.get("key") else ""
    mid = r.y + (r.h - f.ascent) / 2 + 1
    if kind == "button":
        ov.rect(r.x, r.y, r.w, r.h, (0.20, 0.22, 0.27, 1.0) if off else (0.25, 0.33, 0.45, 1.0))
        ov.frame(r.x, r.y, r.w, r.h, (0.4, 0.45, 0.55, 1.0), s)
        text, f = button_label(ov, f, label, key, r.w - 8 * s)
        mid = r.y + (r.h - f.ascent) / 2 + 1
        ov.label(text, r.x + max((r.w - f.width(text)) / 2, 4 * s), mid, fg, max_w=r.w - 8 * s, font=f)
    elif kind == "toggle":
        bx = 16 * s
        ov.frame(r.x + 2 * s, r.y + (r.h - bx) / 2, bx, bx, fg, s)
        if value:
            ov.rect(r.x + 5 * s, r.y + (r.h - bx) / 2 + 3 * s, bx - 6 * s, bx - 6 * s, ACCENT if not off else DIM)
        ov.label(label + key, r.x + bx + 10 * s, mid, fg, max_w=r.w - bx - 12 * s, font=f)
    elif kind in ("slider", "dial"):
        v = float(value) if isinstance(value, (int, float)) else 0.0
        lo, hi = float(spec.get("min", 0.0)), float(spec.get("max", 1.0))
        t = (v - lo) / (hi - lo) if hi != lo else 0.0
        top = r.y + r.h - f.ascent - 2 * s
        vt = format_value(v)
        ov.label(label + key, r.x + 2 * s, top, fg, max_w=r.w - f.width(vt) - 10 * s, font=f)
        ov.label(vt, r.x + r.w - f.width(vt) - 2 * s, top, ACCENT if not off else DIM, font=f)
        ty = r.y + 8 * s
        if kind == "slider":
            x0, x1 = r.x + 10 * s, r.x + r.w - 10 * s
            ov.rect(x0, ty - 2 * s, x1 - x0, 4 * s, (0.3, 0.32, 0.38, 1.0))
            ov.rect(x0, ty - 2 * s, (x1 - x0) * t, 4 * s, ACCENT if not off else DIM)
            ov.rect(x0 + (x1 - x0) * t - 4 * s, ty - 7 * s, 8 * s, 14 * s, fg)
        else:
            cx, rad = r.x + r.w / 2, 9 * s
            ov.label("-", r.x + 6 * s, ty - f.ascent / 2, fg, font=f)
            ov.label("+", r.x + r.w - 14 * s, ty - f.ascent / 2, fg, font=f)
            ov.disc(cx, ty + 2 * s, rad, (0.3, 0.32, 0.38, 1.0))
            ang = np.radians(225.0 - 270.0 * t)
            ov.segment(
                cx,
                ty + 2 * s,
                cx + rad * np.cos(ang),
                ty + 2 * s + rad * np.sin(ang),
                ACCENT if not off else DIM,
                2 * s,
            )
    elif kind == "light":
        state = lights.get(name, value if value in LIGHT_RGBA else "off")
        ov.disc(r.x + 10 * s, r.y + r.h / 2, 7 * s, LIGHT_RGBA.get(state, LIGHT_RGBA["off"]))
        ov.label(label, r.x + 24 * s, mid, fg, max_w=r.w - 26 * s, font=f)
    else:  # text
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = format_value(value)
        shown = label if value in (None, False, "") else f"{label}: {value}" if label else str(value)
        ov.label(shown, r.x + 2 * s, mid, fg, max_w=r.w - 4 * s, font=f)

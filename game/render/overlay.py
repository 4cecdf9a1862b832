"""2-D drawing in window pixels: batched flat shapes and text from a glyph atlas (HUD and control panel).

Shapes and glyph quads are collected in Python lists during a frame and drawn with one call each per
flush, which keeps the panel cheap. Text uses pillow's bundled FreeType font rasterised once into an
atlas texture at the framebuffer's pixel scale (crisp on HiDPI screens).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from chainsim.game.render import shaders

#: ASCII, Latin-1 and the punctuation and symbols instructions tend to use; anything else shows as "?"
CHARS = (
    [chr(c) for c in range(32, 127)]
    + [chr(c) for c in range(161, 256)]
    + list(
        "\u2013\u2014\u2018\u2019\u201c\u201d\u2022\u2026\u2190\u2192\u2191\u2193\u2212\u2264\u2265\u2248\u00b1\u03b1\u03b2\u03bc"
    )
)


#: ASCII stand-ins for characters the bundled font has no glyph for (it would draw an empty box)
FALLBACK = {
    "\u2022": "\u00b7",
    "\u2013": "-",
    "\u2014": "--",
    "\u2212": "-",
    "\u2190": "<-",
    "\u2192": "->",
    "\u2191": "^",
    "\u2193": "v",
    "\u2264": "<=",
    "\u2265": ">=",
    "\u2248": "~",
    "\u00d7": "x",
    "\u03b1": "alpha",
    "\u03b2": "beta",
    "\u03bc": "u",
}

#: most strings (widths) and laid-out lines (glyph quads) kept per font / overlay; a frame of the
#: prp window uses a few hundred, and the same ones frame after frame, so measuring and laying out
#: text is done once instead of every frame (the caches are emptied when they fill up)
TEXT_CACHE = 4096


class Font:
    """Glyph atlas of CHARS in a grid of equal cells; the baseline sits `ascent` below a cell top.
    Characters the font has no glyph for are written with FALLBACK's stand-ins, else "?"."""

    def __init__(self, ctx, size_px: int):

        font = ImageFont.load_default(size=size_px)
        if not isinstance(font, ImageFont.FreeTypeFont):  # Pillow built without FreeType: bitmap font only
            raise RuntimeError("on-screen text needs Pillow with FreeType support")
        self.font = font
        self.ascent, self.descent = self.font.getmetrics()
        notdef = bytes(self.font.getmask("\uffff"))
        missing = {ch for ch in CHARS if ch.isprintable() and ch != " " and bytes(self.font.getmask(ch)) == notdef}
        self.substitute = {ord(ch): FALLBACK.get(ch, "?") for ch in missing}
        chars = [ch for ch in CHARS if ch.isprintable() and ch not in missing]
        self.advance = {ch: float(self.font.getlength(ch)) for ch in chars}
        self.cell_w = int(max(self.font.getbbox(ch)[2] for ch in chars)) + 2
        self.cell_h = self.ascent + self.descent + 2
        cols = 32
        rows = math.ceil(len(chars) / cols)
        img = Image.new("L", (cols * self.cell_w, rows * self.cell_h), 0)
        draw = ImageDraw.Draw(img)
        self.uv = {}
        W, H = img.size
        for i, ch in enumerate(chars):
            cx, cy = (i % cols) * self.cell_w, (i // cols) * self.cell_h
            draw.text((cx + 1, cy + 1), ch, font=self.font, fill=255)
            # atlas rows are uploaded top row first, so v = 0 is the image top
            self.uv[ch] = (cx / W, cy / H, (cx + self.cell_w) / W, (cy + self.cell_h) / H)
        # each glyph's inked box in its cell (x0, y0, x1, y1; pixels from the cell's top left), None for
        # blank ones: text is drawn as these boxes rather than whole cells, which under a software
        # renderer cuts the blended area of a panel's text about three-fold
        ink = np.asarray(img, np.uint8)
        self.ink: dict[str, tuple[int, int, int, int] | None] = {}
        for i, ch in enumerate(chars):
            cx, cy = (i % cols) * self.cell_w, (i // cols) * self.cell_h
            cell = ink[cy : cy + self.cell_h, cx : cx + self.cell_w]
            rows_on, cols_on = np.flatnonzero(cell.any(axis=1)), np.flatnonzero(cell.any(axis=0))
            self.ink[ch] = (
                (int(cols_on[0]), int(rows_on[0]), int(cols_on[-1]) + 1, int(rows_on[-1]) + 1) if len(rows_on) else None
            )
        self.texture = ctx.texture(img.size, 1, img.tobytes())
        self.texture.filter = (ctx.NEAREST, ctx.NEAREST)
        self.line_h = self.ascent + self.descent + 3
        self._widths: dict[str, float] = {}  # text -> width: the panel measures the same strings each frame

    def shown(self, text: str) -> str:
        """`text` as drawn: stand-ins for the characters the font lacks."""
        return text.translate(self.substitute) if self.substitute else text

    def width(self, text: str) -> float:
        w = self._widths.get(text)
        if w is None:
            if len(self._widths) > TEXT_CACHE:
                self._widths.clear()
            w = self._widths[text] = sum(self.advance.get(ch, self.advance["?"]) for ch in self.shown(text))
        return w

    def wrap(self, text: str, width: float) -> list[str]:
        """Greedy word wrap to `width` pixels."""
        out = []
        for para in text.split("\n"):
            line = ""
            for word in para.split(" "):
                trial = f"{line} {word}" if line else word
                if self.width(trial) <= width or not line:
                    line = trial
                else:
                    out.append(line)
                    line = word
            out.append(line)
        return out

    def release(self):
        self.texture.release()


class Overlay:
    """Collects flat shapes and text for one pass over the whole framebuffer."""

    def __init__(self, ctx, font_px: int = 14):
        self.ctx = ctx
        self.flat = ctx.program(vertex_shader=shaders.FLAT2D_VS, fragment_shader=shaders.FLAT2D_FS)
        self.text = ctx.program(vertex_shader=shaders.TEXT_VS, fragment_shader=shaders.TEXT_FS)
        self.font_px = font_px
        self.scale = 1.0
        self.font = Font(ctx, font_px)
        self.small: dict[int, Font] = {}  # smaller atlases for widgets shorter than a text line
        self.shapes: list[float] = []
        self.glyphs: dict[Font, list[float]] = {}
        self._laid_out: dict[tuple, tuple[list[float], float]] = {}  # label arguments -> (glyph quads, pen x)
        self.vbo_shapes = ctx.buffer(reserve=1 << 16, dynamic=True)
        self.vbo_glyphs = ctx.buffer(reserve=1 << 16, dynamic=True)
        self.vao_shapes = ctx.vertex_array(self.flat, [(self.vbo_shapes, "2f 4f", "in_pos", "in_color")])
        self.vao_glyphs = ctx.vertex_array(self.text, [(self.vbo_glyphs, "2f 2f 4f", "in_pos", "in_uv", "in_color")])

    def set_scale(self, scale: float) -> None:
        """Pixels per window unit (HiDPI); rebuilds the atlas at the new size."""
        if abs(scale - self.scale) > 1e-6:
            self.scale = scale
            self.font.release()
            for f in self.small.values():
                f.release()
            self.small.clear()
            self._laid_out.clear()
            self.font = Font(self.ctx, max(6, round(self.font_px * scale)))

    # -- shapes (framebuffer pixels) ---------------------------------------------------------
    def rect(self, x, y, w, h, color) -> None:
        r, g, b, a = color
        x1, y1 = x + w, y + h
        self.shapes += [
            x,
            y,
            r,
            g,
            b,
            a,
            x1,
            y,
            r,
            g,
            b,
            a,
            x1,
            y1,
            r,
            g,
            b,
            a,
            x,
            y,
            r,
            g,
            b,
            a,
            x1,
            y1,
            r,
            g,
            b,
            a,
            x,
            y1,
            r,
            g,
            b,
            a,
        ]

    def frame(self, x, y, w, h, color, t=1.0) -> None:
        self.rect(x, y, w, t, color)
        self.rect(x, y + h - t, w, t, color)
        self.rect(x, y, t, h, color)
        self.rect(x + w - t, y, t, h, color)

    def disc(self, cx, cy, radius, color, segments: int = 24) -> None:
        r, g, b, a = color
        for i in range(segments):
            a0 = 2 * math.pi * i / segments
            a1 = 2 * math.pi * (i + 1) / segments
            self.shapes += [
                cx,
                cy,
                r,
                g,
                b,
                a,
                cx + radius * math.cos(a0),
                cy + radius * math.sin(a0),
                r,
                g,
                b,
                a,
                cx + radius * math.cos(a1),
                cy + radius * math.sin(a1),
                r,
                g,
                b,
                a,
            ]

    def segment(self, x0, y0, x1, y1, color, t=1.5) -> None:
        dx, dy = x1 - x0, y1 - y0
        ln = math.hypot(dx, dy) or 1.0
        nx, ny = -dy / ln * t / 2, dx / ln * t / 2
        r, g, b, a = color
        p = [(x0 + nx, y0 + ny), (x0 - nx, y0 - ny), (x1 - nx, y1 - ny), (x1 + nx, y1 + ny)]
        for i in (0, 1, 2, 0, 2, 3):
            self.shapes += [p[i][0], p[i][1], r, g, b, a]

    # -- text --------------------------------------------------------------------------------
    def font_for(self, height: float) -> Font:
        """The main font, or a smaller one when `height` pixels cannot hold a line of it."""
        if height >= self.font.line_h:
            return self.font
        px = max(7, int(self.font_px * self.scale * height / self.font.line_h))
        if px not in self.small:
            self.small[px] = Font(self.ctx, px)
        return self.small[px]

    @property
    def font_px_base(self) -> float:
        """The main font's size in framebuffer pixels."""
        return self.font_px * self.scale

    def font_sized(self, px: float) -> Font:
        """A font of about `px` framebuffer pixels (headings, small print); atlases are cached by size."""
        px = max(7, int(round(px)))
        if px == self.font.font.size:
            return self.font
        if px not in self.small:
            self.small[px] = Font(self.ctx, px)
        return self.small[px]

    def label(
        self,
        text: str,
        x: float,
        baseline: float,
        color=(1, 1, 1, 1),
        max_w: float | None = None,
        font: Font | None = None,
        bold: bool = False,
        slant: float = 0.0,
    ) -> float:
        """Draw one line with its baseline at `baseline`; returns the pen x after it.

        `bold` draws the glyphs twice one pixel apart (the bundled font has no bold face); `slant`
        leans the glyph tops right by that fraction of the line height (italic)."""
        if bold:
            self.label(text, x + max(1.0, round(self.scale)), baseline, color, max_w, font, False, slant)
        f = font or self.font
        glyphs = self.glyphs.setdefault(f, [])
        text = f.shown(text)
        key = (id(f), text, float(x), float(baseline), tuple(color), max_w, slant)
        hit = self._laid_out.get(key)
        if hit is not None:
            glyphs += hit[0]
            return hit[1]
        if len(self._laid_out) > TEXT_CACHE:
            self._laid_out.clear()
        start = len(glyphs)
        if max_w is not None and f.width(text) > max_w:
            while text and f.width(text + "...") > max_w:
                text = text[:-1]
            text += "..."
        r, g, b, a = color
        pen = float(x)
        # whole pixels: the atlas is sampled nearest, so a fractional offset would drop texel rows
        top = float(round(baseline)) + f.ascent + 1
        bottom = top - f.cell_h
        W, H = f.texture.size
        for ch in text:
            if ch not in f.uv:
                ch = "?"
            box = f.ink[ch]
            if box is None:  # blank (a space): nothing to draw
                pen += f.advance[ch]
                continue
            ix0, iy0, ix1, iy1 = box
            u0, v0 = f.uv[ch][0] + ix0 / W, f.uv[ch][1] + iy0 / H
            u1, v1 = f.uv[ch][0] + ix1 / W, f.uv[ch][1] + iy1 / H
            x0 = float(round(pen)) - 1 + ix0
            x1 = x0 + (ix1 - ix0)
            y1, y0 = top - iy0, top - iy1  # the inked box's top and bottom
            # the slant moves each height by slant x (height above the cell bottom), as for a whole cell
            lean0, lean1 = slant * (y0 - bottom), slant * (y1 - bottom)
            glyphs += _glyph_vertices(x0, x1, y0, y1, lean0, lean1, u0, v0, u1, v1, (r, g, b, a))
            pen += f.advance[ch]
        self._laid_out[key] = (glyphs[start:], pen)
        return pen

    def flush(self, size: tuple[int, int]) -> None:
        """Draw what was collected (shapes under text) over the whole framebuffer, then forget it."""
        ctx = self.ctx
        ctx.disable(ctx.DEPTH_TEST | ctx.CULL_FACE)
        ctx.enable(ctx.BLEND)
        ctx.blend_func = ctx.SRC_ALPHA, ctx.ONE_MINUS_SRC_ALPHA
        batches: list[tuple[list[float], Any, Any, Any, int, Font | None]] = [
            (self.shapes, self.vbo_shapes, self.vao_shapes, self.flat, 6, None)
        ]
        batches += [(g, self.vbo_glyphs, self.vao_glyphs, self.text, 8, f) for f, g in self.glyphs.items()]
        for data, vbo, vao, prog, stride, font in batches:
            if not data:
                continue
            arr = np.asarray(data, np.float32)
            if arr.nbytes > vbo.size:
                vbo.orphan(arr.nbytes * 2)
            vbo.write(arr.tobytes())
            prog["u_screen"].value = (float(size[0]), float(size[1]))
            if font is not None:
                font.texture.use(0)
                prog["u_atlas"].value = 0
            vao.render(ctx.TRIANGLES, vertices=len(arr) // stride)
        self.shapes.clear()
        self.glyphs.clear()

    def release(self) -> None:
        for o in (self.vao_shapes, self.vao_glyphs, self.vbo_shapes, self.vbo_glyphs, self.flat, self.text):
            o.release()
        self.font.release()
        for f in self.small.values():
            f.release()


def _glyph_vertices(x0, x1, y0, y1, lean0, lean1, u0, v0, u1, v1, rgba) -> list[float]:
    """One glyph's quad as two triangles, (x, y, u, v, r, g, b, a) per corner; the top corners lean
    right by `lean1`, the bottom ones by `lean0` (italic)."""
    corners = (
        (x0 + lean0, y0, u0, v1),
        (x1 + lean0, y0, u1, v1),
        (x1 + lean1, y1, u1, v0),
        (x0 + lean0, y0, u0, v1),
        (x1 + lean1, y1, u1, v0),
        (x0 + lean1, y1, u0, v0),
    )
    return [c for corner in corners for c in (*corner, *rgba)]

"""Progress plots for the dashboard: one metric of one trainee over attempts, with the class median.

The thesis tool lets a trainer judge a trainee's progress from saved results (3.3.4); against
the class it also shows whether a trainee is ahead or behind. The k-th point of the median line
is the median over the class's trainees of their k-th attempt, so both lines share the x axis
"attempt number". Rendered on the server with matplotlib's Agg/SVG canvases (no pyplot, no
display, safe from worker threads), so the page needs no JavaScript.

Metrics are the numeric fields of the attempt record (whatever ``RecordStore`` returns), so a
field added to the record gets its plot without a change here.
"""

from __future__ import annotations

import io
import numbers
from collections.abc import Sequence
from typing import Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.backends.backend_svg import FigureCanvasSVG
from matplotlib.figure import Figure

FORMATS = {"svg": "image/svg+xml", "png": "image/png"}
_NOT_METRICS = {"id"}
_UNITS = {"_mm": "mm", "_s": "s", "_deg": "deg"}


def _is_number(value: Any) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def metrics(attempts: Sequence[dict[str, Any]]) -> list[str]:
    """Numeric fields of the records, in record order (None allowed: no value that time)."""
    if not attempts:
        return []
    out = []
    for key in attempts[0]:
        if key in _NOT_METRICS:
            continue
        values = [a.get(key) for a in attempts]
        if all(v is None or _is_number(v) for v in values) and any(_is_number(v) for v in values):
            out.append(key)
    return out


def label(metric: str) -> str:
    """``needle_error_mm`` -> ``needle error (mm)``."""
    for suffix, unit in _UNITS.items():
        if metric.endswith(suffix):
            return f"{metric[: -len(suffix)].replace('_', ' ')} ({unit})"
    return metric.replace("_", " ")


def render(
    attempts: Sequence[dict[str, Any]],
    median: Sequence[float | None],
    metric: str,
    title: str,
    fmt: str = "svg",
    *,
    ylabel: str = "",
    benchmark: tuple[float, str] | None = None,
) -> bytes:
    """The plot as SVG or PNG bytes; ``benchmark`` (value, words) is drawn as a horizontal line."""
    # sized so a phone (390 px) draws it at about 3/4 size with its text still about 10 px
    fig = Figure(figsize=(4.8, 3.2), dpi=100)
    canvas = (FigureCanvasSVG if fmt == "svg" else FigureCanvasAgg)(fig)
    ax = fig.subplots()
    ax.tick_params(labelsize=10)
    xs = list(range(1, len(attempts) + 1))
    own = [(x, float(a[metric])) for x, a in zip(xs, attempts) if _is_number(a.get(metric))]
    if own:
        ax.plot([x for x, _ in own], [y for _, y in own], marker="o", color="tab:blue", label="this trainee")
    med = [(k + 1, v) for k, v in enumerate(median) if v is not None]
    if med:
        ax.plot(
            [x for x, _ in med], [y for _, y in med], linestyle="--", color="0.45", marker=".", label="class median"
        )
    if benchmark is not None:
        ax.axhline(benchmark[0], color="tab:red", linestyle=":", label=benchmark[1])
    ax.set_xlabel("attempt", fontsize=11)
    ax.set_ylabel(ylabel or label(metric), fontsize=11)
    ax.set_title(title, fontsize=11)
    ax.grid(alpha=0.3)
    if own or med or benchmark is not None:
        ax.legend(loc="best", fontsize=10)
    if len(xs) <= 20 and xs:
        ax.set_xticks(xs)
    fig.tight_layout()
    buf = io.BytesIO()
    if fmt == "svg":
        # No date in the metadata: the same attempts give the same bytes.
        fig.savefig(buf, format="svg", metadata={"Date": None})
    else:
        assert isinstance(canvas, FigureCanvasAgg)  # made above for any format but svg
        canvas.print_png(buf)
    return buf.getvalue()


#: a force profile's event bit for a boundary that gave (chainsim.systems.engine.haptics.model.EV_PUNCTURE)
_PUNCTURE = 1


def force_profile(profile: Sequence[Sequence[float]], title: str, against: str = "depth") -> bytes:
    """An attempt's force profile as SVG: the force the hand felt through the device against the needle's
    depth (in and out, ``against="depth"``) or against time (``"time"``), each puncture marked where the
    layer gave. ``profile`` rows are (time s, depth mm, force N, events), as the simulator stores them
    (details.force_profile). One panel a plot, so a narrow screen stacks them at a readable size."""
    rows = [r for r in profile if len(r) >= 4 and all(_is_number(x) for x in r[:4])]
    fig = Figure(figsize=(4.8, 3.2), dpi=100)
    FigureCanvasSVG(fig)
    ax = fig.subplots()
    xs = [float(r[1 if against == "depth" else 0]) for r in rows]
    force = [float(r[2]) for r in rows]
    # each puncture marked where the layer gave: the point before the force dropped
    pops = [max(k - 1, 0) for k, r in enumerate(rows) if int(r[3]) & _PUNCTURE]
    ax.plot(xs, force, lw=1.0, color="tab:blue", label="force")
    if pops:
        ax.plot([xs[k] for k in pops], [force[k] for k in pops], "v", color="tab:red", ms=7, label="puncture")
        ax.legend(loc="best", fontsize=10)
    ax.axhline(0.0, color="0.6", lw=0.5)
    ax.grid(alpha=0.3)
    ax.tick_params(labelsize=10)
    ax.set_xlabel("needle depth (mm)" if against == "depth" else "time (s)", fontsize=11)
    ax.set_ylabel("force against insertion (N)", fontsize=11)
    ax.set_title(title, fontsize=11)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="svg", metadata={"Date": None})
    return buf.getvalue()

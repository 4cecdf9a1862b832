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
    fig = Figure(figsize=(6.4, 3.2), dpi=100)
    canvas = (FigureCanvasSVG if fmt == "svg" else FigureCanvasAgg)(fig)
    ax = fig.subplots()
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
    ax.set_xlabel("attempt")
    ax.set_ylabel(ylabel or label(metric))
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    if own or med or benchmark is not None:
        ax.legend(loc="best", fontsize=8)
    if len(xs) <= 20 and xs:
        ax.set_xticks(xs)
    fig.tight_layout()
    buf = io.BytesIO()
    if fmt == "svg":
        # No date in the metadata: the same attempts give the same bytes.
        fig.savefig(buf, format="svg", metadata={"Date": None})
    else:
        canvas.print_png(buf)
    return buf.getvalue()


#: a force profile's event bit for a boundary that gave (chainsim.systems.engine.haptics.model.EV_PUNCTURE)
_PUNCTURE = 1


def force_profile(profile: Sequence[Sequence[float]], title: str) -> bytes:
    """An attempt's force profile as SVG: the force the hand felt through the device against the needle's
    depth (in and out) and against time, each puncture marked. ``profile`` rows are (time s, depth mm,
    force N, events), as the simulator stores them (details.force_profile)."""
    rows = [r for r in profile if len(r) >= 4 and all(_is_number(x) for x in r[:4])]
    fig = Figure(figsize=(6.4, 3.0), dpi=100)
    FigureCanvasSVG(fig)
    ax_d, ax_t = fig.subplots(1, 2)
    t, depth, force = ([float(r[k]) for r in rows] for k in range(3))
    # each puncture marked where the layer gave: the point before the force dropped
    pops = [max(k - 1, 0) for k, r in enumerate(rows) if int(r[3]) & _PUNCTURE]
    ax_d.plot(depth, force, lw=0.9, color="tab:blue")
    ax_t.plot(t, force, lw=0.9, color="tab:blue", label="force")
    for ax, xs in ((ax_d, depth), (ax_t, t)):
        if pops:
            ax.plot([xs[k] for k in pops], [force[k] for k in pops], "v", color="tab:red", label="puncture")
        ax.axhline(0.0, color="0.6", lw=0.5)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=8)
    ax_d.set_xlabel("needle depth (mm)", fontsize=9)
    ax_d.set_ylabel("force against insertion (N)", fontsize=9)
    ax_t.set_xlabel("time (s)", fontsize=9)
    if pops:
        ax_t.legend(loc="best", fontsize=8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="svg", metadata={"Date": None})
    return buf.getvalue()

"""Trainee-record reports: aligned tables, CSV export and the progress plot (thesis 3.3.4, 6.1.5).

The thesis tool lets trainer and trainee look back over saved results to judge progress; here
that is a text table, a CSV for spreadsheets and a PNG of the two 6.1.5 errors and the X-ray each
attempt cost (images and seconds of exposure, thesis 3.2.3) over attempts.
Files are written to a temporary sibling and renamed into place, so an interrupted export never
leaves a half-written file under the requested name.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, Any

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from chainsim.game.records.validate import AIDS, printable
from chainsim.systems.engine.atomicfile import atomic_open
from chainsim.systems.engine.errors import UserError
from chainsim.systems.procedures import records_layout

#: the attempt as the records keep it (the fixed columns' procedure, chainsim.systems.procedures)
LAYOUT = records_layout()

CSV_COLUMNS = (
    "id",
    "class_name",
    "trainee",
    "pack",
    "created_at",
    # the fixed fields of the needle procedure's attempt (its declared layout, LAYOUT)
    *(c.name for c in LAYOUT.columns[:3]),
    "target",
    *(c.name for c in LAYOUT.columns[3:]),
    *(f"aid_{name}" for name in AIDS),
    "step_times",
    "details",
    "metrics",  # the procedure's own metrics (records' procedure-neutral table), JSON
    # provenance (docs/records-server.md): local, replayed or witnessed; why the input is beyond a
    # person's, if it is; who accepted it anyway
    "source",
    "flags",
    "accepted_by",
)


def table(headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    """Left-aligned text columns, numbers right-aligned, one header rule."""
    cells = [[_cell(v) for v in row] for row in rows]
    widths = [len(h) for h in headers]
    for row in cells:
        widths = [max(w, len(c)) for w, c in zip(widths, row)]
    numeric = [
        bool(rows) and all(isinstance(row[i], (int, float)) or row[i] is None for row in rows)
        for i in range(len(headers))
    ]

    def line(values: Sequence[str]) -> str:
        parts = [v.rjust(w) if num else v.ljust(w) for v, w, num in zip(values, widths, numeric)]
        return "  ".join(parts).rstrip()

    out = [line(headers), line(["-" * w for w in widths])]
    out += [line(row) for row in cells]
    return "\n".join(out)


def _cell(value: Any) -> str:
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.2f}"
    return printable(str(value))  # a name stored by an older version shows its hidden characters


def atomic_write(path: Path, write: Callable[[IO[Any]], object], *, binary: bool) -> None:
    """Write through `write(fh)` atomically (chainsim.systems.engine.atomicfile), after checking the folder."""
    path = Path(path)
    if path.is_dir():
        raise UserError(f"output {path} is a directory; expected a file name")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise UserError(f"output folder {folder} does not exist")
    try:
        with atomic_open(path, "wb" if binary else "w", newline="") as fh:
            write(fh)
    except OSError as exc:
        raise UserError(f"cannot write {path}: {exc.strerror or exc}") from None


#: first characters a spreadsheet reads as the start of a formula (OWASP's list for CSV injection)
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")


def neutral(value: Any) -> Any:
    """A text cell a spreadsheet would run as a formula, made inert by a leading apostrophe.

    Names and packs are the trainees' own text, and a trainer opens the export in a spreadsheet:
    ``=HYPERLINK(...)`` in a trainee's name must arrive as text. Numbers stay numbers."""
    if isinstance(value, str) and value.startswith(FORMULA_STARTS):
        return "'" + value
    return value


def _figures(a: dict[str, Any]) -> list[Any]:
    """The figure columns' cells of one attempt. An attempt of another procedure (it names it) has none of
    these figures: its cells are empty, its own figures are in its metrics."""
    if "procedure" in a:
        return [""] * len(LAYOUT.columns)
    first = ["" if a[c.name] is None else a[c.name] for c in LAYOUT.columns[:3]]
    # figures later versions added read as their defaults in an attempt made without them; counts are whole
    return [
        *first,
        *(a[c.name] for c in LAYOUT.columns[3:5]),
        *(a.get(c.name, 0 if c.whole else 0.0) for c in LAYOUT.columns[5:]),
    ]


def csv_rows(attempts: Sequence[dict[str, Any]]) -> list[list[Any]]:
    """The export's rows: one per attempt, text cells neutralised (``neutral``)."""
    rows = []
    for a in attempts:
        rows.append(
            [
                a["id"],
                a["class_name"],
                a["trainee"],
                a["pack"],
                a["created_at"],
                *_figures(a)[:3],
                a["target"],
                *_figures(a)[3:],
                *(int(bool(a["aids"].get(name, False))) for name in AIDS),
                json.dumps(a["step_times"], sort_keys=True),
                json.dumps(a["details"], sort_keys=True),
                json.dumps(a.get("metrics") or {}, sort_keys=True),
                a.get("source", "local"),
                "; ".join(a.get("flags") or []),
                a.get("accepted_by") or "",
            ]
        )
    return [[neutral(cell) for cell in row] for row in rows]


def export_csv(attempts: Sequence[dict[str, Any]], path: Path) -> None:
    """One header row then one row per attempt; aids as 0/1 columns, dicts as JSON text."""

    def write(fh: Any) -> None:
        w = csv.writer(fh)
        w.writerow(CSV_COLUMNS)
        w.writerows(csv_rows(attempts))

    atomic_write(path, write, binary=False)


def plot_progress(attempts: Sequence[dict[str, Any]], path: Path, title: str) -> None:
    """PNG of the two errors of 6.1.5 (the marked points', the needle's) and the X-ray each attempt cost
    against attempt number (Agg); each error's axis is named by its words in the procedure's layout."""
    if not attempts:
        raise UserError(f"no attempts to plot for {title}")
    if Path(path).suffix.lower() != ".png":
        raise UserError(f"plot output {path} must end in .png")

    n = list(range(1, len(attempts) + 1))
    words = {c.name: c.words.lower() for c in LAYOUT.columns}
    marks = [float("nan") if a.get(LAYOUT.mark_error) is None else a[LAYOUT.mark_error] for a in attempts]
    needle = [float("nan") if a.get(LAYOUT.target_error) is None else a[LAYOUT.target_error] for a in attempts]
    shots = [a.get("xray_shots", 0) for a in attempts]
    exposure = [a.get("exposure_s", 0.0) for a in attempts]

    fig = Figure(figsize=(7.0, 7.5), dpi=100)
    FigureCanvasAgg(fig)
    ax_l, ax_n, ax_x = fig.subplots(3, 1, sharex=True)
    ax_l.plot(n, marks, marker="o", color="tab:blue")
    ax_l.set_ylabel(f"{words[LAYOUT.mark_error]} E (mm)")
    ax_l.set_ylim(bottom=0)
    ax_l.grid(alpha=0.3)
    # Attempts with no needle contact have no needle error: join the others, mark the gaps.
    hit = [(i, v) for i, v in zip(n, needle) if v == v]
    missing = [i for i, v in zip(n, needle) if v != v]
    if hit:
        ax_n.plot([i for i, _ in hit], [v for _, v in hit], marker="s", color="tab:red")
    for i in missing:
        ax_n.axvline(i, color="0.7", linestyle=":", linewidth=1)
    ax_n.axhline(0.0, color="0.4", linewidth=0.8)
    ax_n.set_ylabel(f"{words[LAYOUT.target_error]} (mm)")
    ax_n.grid(alpha=0.3)
    # X-ray: images as bars, seconds of exposure as a line on a second axis (thesis 3.2.3)
    ax_x.bar(n, shots, color="tab:gray", alpha=0.6, label="X-ray images")
    ax_x.set_ylabel("X-ray images")
    ax_x.set_ylim(bottom=0)
    ax_x.grid(alpha=0.3)
    ax_e = ax_x.twinx()
    ax_e.plot(n, exposure, marker="^", color="tab:purple", label="exposure (s)")
    ax_e.set_ylabel("exposure (s)")
    ax_e.set_ylim(bottom=0)
    ax_x.set_xlabel("attempt" + (" (dotted: no needle contact)" if missing else ""))
    ax_x.set_xticks(n if len(n) <= 20 else n[:: max(1, len(n) // 10)])
    fig.suptitle(title)
    fig.tight_layout()

    atomic_write(path, lambda fh: fig.savefig(fh, format="png"), binary=True)

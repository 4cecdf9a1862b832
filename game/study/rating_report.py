"""The report of a blinded rating: how far the raters agree, and how each simulator metric goes with them.

`analyse` reads a rating set (chainsim.game.study.rating.ratings_table) and the rated attempts' metrics
and gives the agreement (chainsim.game.study.agreement.icc over the attempts every rater marked) and
Spearman's rho of each of the pack's metrics with the raters' mean score. `write` puts ratings.csv (one
row per coded attempt: each rater's score, the mean, the metrics), ratings.png (each attempt's scores by
rater, attempts ordered by their mean: agreeing raters' marks lie together) and agreement.md into a
folder, and returns the report's path.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only: no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from chainsim.game.records.store import RecordStore  # noqa: E402
from chainsim.game.study import agreement, rating  # noqa: E402
from chainsim.systems.engine.errors import UserError  # noqa: E402


@dataclass(slots=True)
class RatingStudy:
    name: str
    raters: list[str]
    rows: list[dict]  # rating.ratings_table rows, each with "metrics" added
    complete: int  # attempts every rater marked
    agreement: agreement.Agreement | None
    correlations: list[dict]
    source: str


def analyse(store: RecordStore, name: str, specs: dict[str, dict], source: str) -> RatingStudy:
    """The rating set `name` analysed against the pack's [metrics] `specs`."""
    table = rating.ratings_table(store, name)
    rows = table["rows"]
    metrics = {}
    for r in rows:
        metrics[r["attempt_id"]] = dict(store.get_attempt(r["attempt_id"]).get("metrics") or {})
        r["metrics"] = metrics[r["attempt_id"]]
    scores, full = agreement.complete(rows, table["raters"])
    if len(full) < 3:
        raise UserError(
            f"rating set {name!r}: {len(full)} of {len(rows)} attempts are marked by every rater; agreement needs 3"
        )
    return RatingStudy(
        name=name,
        raters=table["raters"],
        rows=rows,
        complete=len(full),
        agreement=agreement.icc(scores),
        correlations=agreement.metric_correlations(rows, metrics, specs),
        source=source,
    )


NO_AVERAGE = (
    "The attempts differ by no more than the raters disagree: the mean of the raters has no agreement to "
    "report (ICC(A,k) falls to minus infinity, shown as -)."
)


def _num(x: float | None, digits: int = 2) -> str:
    return "-" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def _csv(study: RatingStudy, path: Path) -> None:
    names = sorted({m for r in study.rows for m in r["metrics"]})
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(["code", "attempt_id", *[f"rater:{n}" for n in study.raters], "mean", *names])
        for r in study.rows:
            marks = [r["scores"].get(n) for n in study.raters]
            given = [m for m in marks if m is not None]
            mean = float(np.mean(given)) if given else None
            w.writerow([r["code"], r["attempt_id"], *["" if m is None else m for m in marks], _num(mean),
                        *["" if r["metrics"].get(m) is None else r["metrics"][m] for m in names]])  # fmt: skip


def _plot(study: RatingStudy, path: Path) -> None:
    rows = [r for r in study.rows if all(r["scores"].get(n) is not None for n in study.raters)]
    rows.sort(key=lambda r: np.mean([r["scores"][n] for n in study.raters]))
    fig, ax = plt.subplots(figsize=(8, 4), constrained_layout=True)
    x = np.arange(1, len(rows) + 1)
    for k, n in enumerate(study.raters):
        ax.plot(x + (k - (len(study.raters) - 1) / 2) * 0.08, [r["scores"][n] for r in rows], "o", label=n, ms=5)
    ax.set_xlabel("attempt, ordered by the raters' mean score")
    ax.set_ylabel("global rating (5-25)")
    a = study.agreement
    if a is not None:
        ax.set_title(f"{study.name}: ICC(A,1) {_num(a.single)} ({_num(a.single_ci[0])} to {_num(a.single_ci[1])})")
    ax.grid(alpha=0.3)
    ax.legend(title="rater", fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write(study: RatingStudy, out: Path) -> Path:
    _csv(study, out / "ratings.csv")
    _plot(study, out / "ratings.png")
    a = study.agreement
    lines = [
        f"# Blinded rating {study.name}: agreement and the simulator's metrics",
        "",
        f"Source: {study.source}. {len(study.rows)} attempts under codes, {len(study.raters)} raters "
        f"({', '.join(study.raters)}); {study.complete} attempts were marked by every rater and count in the "
        "agreement.",
        "",
        "## Inter-rater agreement",
        "",
        "Intraclass correlation, two-way random effects, absolute agreement (McGraw and Wong 1996, case 2A).",
        "",
        "| | ICC | 95 % interval |",
        "|---|---|---|",
    ]
    if a is not None:
        lines += [
            f"| one rater, ICC(A,1) | {_num(a.single)} | {_num(a.single_ci[0])} to {_num(a.single_ci[1])} |",
            f"| mean of {a.k} raters, ICC(A,{a.k}) | {_num(a.average)} | {_num(a.average_ci[0])} to "
            f"{_num(a.average_ci[1])} |",
            "",
            f"F({a.df1}, {a.df2}) = {_num(a.f)}, p = {_num(a.p, 4)} (attempts differ beyond the raters' disagreement).",
        ]
        if not np.isfinite(a.average):
            lines += ["", NO_AVERAGE]
    lines += [
        "",
        "## Each metric against the raters",
        "",
        "Spearman's rho of the metric with the raters' mean score, oriented so that a positive rho means the "
        "metric is better where the raters judged the attempt better.",
        "",
        "| metric | attempts | rho | p |",
        "|---|---|---|---|",
    ]
    for c in study.correlations:
        lines.append(f"| {c['label']} | {c['n']} | {_num(c['rho'])} | {_num(c['p'], 4)} |")
    lines += ["", "![each attempt's scores by rater](ratings.png)", ""]
    md = out / "agreement.md"
    md.write_text("\n".join(lines), encoding="utf-8")
    return md

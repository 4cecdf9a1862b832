"""A validity study's report: the statistics of every metric of a pack, their plots, CSV and report.md.

``analyse`` turns a ``Selection`` (``chainsim.game.study.validity_data``) into one value per
participant and metric and runs ``chainsim.game.study.validity`` on each of the pack's [metrics];
``write`` puts into a folder one PNG per metric (both groups' values, their fitted distributions, the
contrasting-groups pass mark and the pack's benchmark), ``learning-curves.png`` (each participant's
values over their attempts), ``statistics.csv`` and ``report.md``. When any attempt was made by a
script or drawn by the synthetic cohort builder, report.md opens with "synthetic data: not evidence".
Files are written to a temporary sibling and renamed into place.
"""

from __future__ import annotations

import csv
import io
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator
from scipy import stats

from chainsim.game.study import validity
from chainsim.game.study.validity import MetricResult
from chainsim.game.study.validity_data import GROUPS, Selection, metric_value, participant_value
from chainsim.systems.engine import atomicfile
from chainsim.systems.engine.errors import UserError

SYNTHETIC = "synthetic data: not evidence"
COLOURS = {"novice": "tab:orange", "expert": "tab:blue"}
CSV_COLUMNS = (
    "metric",
    "label",
    "units",
    "lower_is_better",
    "novices",
    "experts",
    "novice_median",
    "novice_median_low",
    "novice_median_high",
    "expert_median",
    "expert_median_low",
    "expert_median_high",
    "mann_whitney_u",
    "p_value",
    "cliffs_delta",
    "cliffs_delta_low",
    "cliffs_delta_high",
    "cohens_d",
    "cohens_d_low",
    "cohens_d_high",
    "separates",
    "pass_mark",
    "false_pass_fitted",
    "false_fail_fitted",
    "false_pass_observed",
    "false_fail_observed",
    "benchmark",
    "benchmark_source",
    "notes",
)


@dataclass
class Study:
    """The analysis of one pack's metrics over a selection of attempts, and what it was made from."""

    pack: str
    source: str
    selection: Selection
    unit: str
    seed: int
    resamples: int
    results: list[MetricResult] = field(default_factory=list)
    #: metric -> participant -> their values, oldest attempt first (None: the attempt has no value)
    curves: dict[str, dict[str, list[float | None]]] = field(default_factory=dict)
    synthetic_cohort: bool = False

    @property
    def synthetic(self) -> bool:
        return self.synthetic_cohort or self.selection.synthetic > 0


def analyse(
    selection: Selection,
    metrics: dict[str, dict[str, Any]],
    *,
    pack: str,
    source: str,
    unit: str = "median",
    seed: int = 0,
    resamples: int = validity.RESAMPLES,
    synthetic_cohort: bool = False,
) -> Study:
    """Every metric of `metrics` (a pack's [metrics] section) over the selected participants."""
    study = Study(pack, source, selection, unit, seed, resamples, synthetic_cohort=synthetic_cohort)
    rng = np.random.default_rng(seed)
    for name, spec in metrics.items():
        series = {p: [metric_value(a, name) for a in own] for p, own in selection.series.items()}
        study.curves[name] = series
        per = {g: [participant_value(series[p], unit) for p in selection.in_group(g)] for g in GROUPS}
        study.results.append(
            validity.analyse_metric(name, spec, per["novice"], per["expert"], rng=rng, resamples=resamples)
        )
    return study


def number(x: float | None) -> str:
    """A figure for a table: three significant digits, whole numbers from 1000."""
    if x is None or not math.isfinite(x):
        return "-"
    return f"{x:.0f}" if abs(x) >= 1000 else f"{x:.3g}"


def interval(ci: tuple[float, float] | None) -> str:
    return f"[{number(ci[0])}, {number(ci[1])}]" if ci else "[-]"


def percent(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f} %"


def file_name(metric: str) -> str:
    """The PNG of a metric: its name with anything but letters, digits, '_', '.' and '-' made '_'."""
    return "metric-" + re.sub(r"[^A-Za-z0-9_.-]", "_", metric) + ".png"


def csv_row(r: MetricResult) -> list[Any]:
    m = r.mark

    def ends(ci: tuple[float, float] | None) -> list[Any]:
        return list(ci) if ci else ["", ""]

    return [
        r.name,
        r.label,
        r.units,
        r.lower_is_better,
        len(r.novice),
        len(r.expert),
        "" if r.novice_median is None else r.novice_median,
        *ends(r.novice_ci),
        "" if r.expert_median is None else r.expert_median,
        *ends(r.expert_ci),
        "" if r.u is None else r.u,
        "" if r.p is None else r.p,
        "" if r.delta is None else r.delta,
        *ends(r.delta_ci),
        "" if r.d is None else r.d,
        *ends(r.d_ci),
        r.separates,
        *("" if m.get(k) is None else m[k] for k in ("mark", "false_pass", "false_fail")),
        *("" if m.get(k) is None else m[k] for k in ("observed_false_pass", "observed_false_fail")),
        "" if r.benchmark is None else r.benchmark,
        r.benchmark_source,
        "; ".join(r.notes),
    ]


def statistics_csv(study: Study) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for r in study.results:
        w.writerow(csv_row(r))
    return buf.getvalue()


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    FigureCanvasAgg(fig).print_png(buf)
    return buf.getvalue()


def metric_plot(r: MetricResult) -> bytes:
    """Both groups' values (left) and their fitted normal densities (right), the pass mark and benchmark."""
    fig = Figure(figsize=(8, 4.2))
    left, right = fig.subplots(1, 2, sharey=True, gridspec_kw={"width_ratios": [1.2, 1]})
    jitter = np.random.default_rng(0)
    for i, (group, values) in enumerate((("novice", r.novice), ("expert", r.expert))):
        xs = i + jitter.uniform(-0.15, 0.15, len(values))
        left.scatter(xs, values, s=18, alpha=0.7, color=COLOURS[group], label=f"{group}s (n = {len(values)})")
        med, ci = (r.novice_median, r.novice_ci) if group == "novice" else (r.expert_median, r.expert_ci)
        if med is not None:
            err = [[med - ci[0]], [ci[1] - med]] if ci else None
            left.errorbar([i + 0.3], [med], yerr=err, fmt="s", color="black", capsize=4)
        if len(values) >= 2 and np.std(values) > 0:
            ys = np.linspace(values.min() - values.std(), values.max() + values.std(), 200)
            right.plot(stats.norm.pdf(ys, values.mean(), values.std(ddof=1)), ys, color=COLOURS[group])
    left.set_xticks([0, 1], ["novices", "experts"])
    left.set_ylabel(f"{r.label} ({r.units})" if r.units else r.label)
    left.set_title("values (square: median, 95 % CI)", fontsize=9)
    right.set_title("fitted normal distributions", fontsize=9)
    right.set_xlabel("density")
    mark = r.mark.get("mark")
    for ax in (left, right):
        if mark is not None:
            ax.axhline(mark, color="tab:red", linestyle="--", label=f"pass mark {number(mark)}")
        if r.benchmark is not None:
            ax.axhline(r.benchmark, color="grey", linestyle=":", label=f"pack benchmark {number(r.benchmark)}")
    left.legend(fontsize=7, loc="best")
    better = "lower" if r.lower_is_better else "higher"
    fig.suptitle(f"{r.label}: {better} is better; Cliff's delta {number(r.delta)} {interval(r.delta_ci)}")
    fig.tight_layout()
    return _png(fig)


def curves_plot(study: Study) -> bytes:
    """One panel per metric: each participant's values over their attempts and each group's median."""
    n = max(len(study.results), 1)
    cols = min(4, n)
    rows = math.ceil(n / cols)
    fig = Figure(figsize=(3.4 * cols, 2.6 * rows + 0.6))
    axes = np.atleast_1d(fig.subplots(rows, cols, squeeze=False)).ravel()
    for ax, r in zip(axes, study.results):
        series = study.curves[r.name]
        for group in GROUPS:
            people = study.selection.in_group(group)
            for p in people:
                ys = [np.nan if v is None else v for v in series[p]]
                ax.plot(range(1, len(ys) + 1), ys, color=COLOURS[group], alpha=0.25, linewidth=0.8)
            med = validity.curve_medians([series[p] for p in people])
            ax.plot(
                range(1, len(med) + 1),
                [np.nan if v is None else v for v in med],
                color=COLOURS[group],
                linewidth=2.2,
                label=f"{group}s' median",
            )
        ax.set_title(r.label, fontsize=9)
        ax.set_xlabel("attempt", fontsize=8)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.tick_params(labelsize=7)
    for ax in axes[len(study.results) :]:
        ax.set_visible(False)
    axes[0].legend(fontsize=7)
    fig.suptitle("Learning curves: each participant's attempts, oldest first (thin), and each group's median")
    fig.tight_layout()
    return _png(fig)


def _save(path: Path, data: bytes) -> None:
    try:
        atomicfile.write_bytes(path, data)
    except OSError as e:
        raise UserError(f"--out {path}: cannot write ({e.strerror or e})") from None


def write(study: Study, out: Path) -> Path:
    """The report's files in folder `out` (which exists); returns report.md's path."""
    for r in study.results:
        _save(out / file_name(r.name), metric_plot(r))
    _save(out / "learning-curves.png", curves_plot(study))
    _save(out / "statistics.csv", statistics_csv(study).encode("utf-8"))
    md = out / "report.md"
    _save(md, markdown(study).encode("utf-8"))
    return md


def _synthetic_banner(study: Study) -> list[str]:
    if not study.synthetic:
        return []
    sel = study.selection
    why = (
        "every attempt was drawn by chainsim's synthetic cohort builder from stated distributions"
        if study.synthetic_cohort
        else f"{sel.synthetic} of the {sel.attempts} attempts were made by an input script or drawn "
        "by the synthetic cohort builder, not by a person"
    )
    return [
        f"**{SYNTHETIC}.** This report shows how the analysis works; {why}. "
        "Nothing in it says how well the simulator's metrics tell experts from novices.",
        "",
    ]


def _source(study: Study) -> list[str]:
    sel = study.selection
    nov, exp = len(sel.in_group("novice")), len(sel.in_group("expert"))
    sources = ", ".join(f"{n} {s}" for s, n in sorted(sel.sources.items())) or "none"
    groups = "a register" if sel.groups_from == "register" else "the attempts' own details.protocol.group"
    lines = [
        f"Data source: {study.source}.",
        "",
        f"- Attempts used: {sel.attempts} ({sources}); participants: {nov} novices, {exp} experts "
        f"(groups from {groups}).",
        f"- Each participant counts once per metric: the {study.unit} of their attempts' values.",
    ]
    for why, n in sorted(sel.left_out.items()):
        lines.append(f"- Left out: {n} attempts {why}.")
    if sel.ungrouped:
        lines.append(f"- Participants with attempts but no group: {', '.join(sorted(sel.ungrouped))}.")
    if sel.absent:
        lines.append(f"- On the register without attempts: {', '.join(sel.absent)}.")
    return lines + [""]


def _table(study: Study) -> list[str]:
    lines = [
        "| Metric | Better | Novices: n, median [95 % CI] | Experts: n, median [95 % CI] | U | p "
        "| Cliff's delta [95 % CI] | Cohen's d [95 % CI] | Pass mark | False pass | False fail | Separates |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in study.results:
        m = r.mark
        unit = f" ({r.units})" if r.units else ""
        lines.append(
            f"| {r.label}{unit} | {'lower' if r.lower_is_better else 'higher'} "
            f"| {len(r.novice)}, {number(r.novice_median)} {interval(r.novice_ci)} "
            f"| {len(r.expert)}, {number(r.expert_median)} {interval(r.expert_ci)} "
            f"| {number(r.u)} | {'-' if r.p is None else f'{r.p:.3g}'} "
            f"| {number(r.delta)} {interval(r.delta_ci)} | {number(r.d)} {interval(r.d_ci)} "
            f"| {number(m.get('mark'))} | {percent(m.get('false_pass'))} | {percent(m.get('false_fail'))} "
            f"| {'yes' if r.separates else '**no**'} |"
        )
    return lines + [""]


def _summary(study: Study) -> list[str]:
    good = [r.label for r in study.results if r.separates]
    flagged = [r for r in study.results if not r.separates]
    lines = [f"{len(good)} of {len(study.results)} metrics separate the groups (the effect's 95 % CI lies above 0)."]
    if good:
        lines.append(f"Separating: {', '.join(good)}.")
    if flagged:
        lines += ["", "Flagged, these do not separate novices from experts in these data:", ""]
        lines += [f"- **{r.label}** (`{r.name}`): {'; '.join(r.notes)}." for r in flagged]
    return lines + [""]


def _marks(study: Study) -> list[str]:
    lines = []
    for r in study.results:
        m = r.mark
        unit = f" {r.units}" if r.units else ""
        bench = (
            f"pack benchmark {number(r.benchmark)}{unit} "
            f"({r.benchmark_basis}; source: {r.benchmark_source or 'not stated'})"
            if r.benchmark is not None
            else "no pack benchmark"
        )
        if m.get("mark") is not None:
            mark = (
                f"contrasting-groups mark {number(m['mark'])}{unit}: false pass {percent(m['false_pass'])}, "
                f"false fail {percent(m['false_fail'])} fitted ({percent(m['observed_false_pass'])}, "
                f"{percent(m['observed_false_fail'])} observed)"
            )
        else:
            mark = f"no contrasting-groups mark ({m.get('why', 'too few participants')})"
        lines.append(f"- **{r.label}**: {bench}; {mark}. ![{r.label}]({file_name(r.name)})")
    return lines + [""]


def _methods(study: Study) -> list[str]:
    return [
        f"Group medians with bootstrap {validity.CONFIDENCE:.0%} CIs (BCa, {study.resamples} resamples, seed "
        f"{study.seed}; scipy {scipy.__version__}). Mann-Whitney U, two-sided: U counts the novice-expert pairs "
        "in which the novice's value is the larger (ties one half). Cliff's delta (the rank-biserial r) is "
        "P(expert better) - P(novice better), positive when the experts do better; its CI by the two-sample "
        "bootstrap (each group resampled on its own). A metric whose CI of the effect covers 0 is flagged. "
        "Cohen's d (pooled spread, same orientation) is given for comparison. The pass mark is where normal "
        "distributions fitted to the two groups cross between their means (contrasting-groups method); its "
        "false-pass rate is the share of the fitted novices that pass, its false-fail rate the share of the "
        "fitted experts that fail. Groups of fewer than "
        f"{validity.MIN_PER_GROUP} participants with a value are not tested.",
        "",
    ]


def markdown(study: Study) -> str:
    """report.md: the synthetic banner when it applies, data source, summary, table, marks, curves, methods."""
    lines = _synthetic_banner(study)
    lines += [f"# Validity study: {study.pack}", ""]
    lines += _source(study)
    lines += ["## Summary", ""] + _summary(study)
    lines += ["## Statistics per metric", ""] + _table(study)
    lines += ["## Pass marks and the pack's benchmarks", ""] + _marks(study)
    lines += ["## Learning curves", "", "![learning curves](learning-curves.png)", ""]
    lines += ["## Methods", ""] + _methods(study)
    return "\n".join(lines)

"""The statistics of a known-groups validity study: does a metric tell experienced participants from novices?

A simulator's metric earns its place in an assessment when people who can do the procedure score
better on it than people who cannot (known-groups, or contrasting-groups, validity). Given one value
per participant for each group, this module gives per metric:

- each group's median with a bootstrap 95 % confidence interval (``scipy.stats.bootstrap``, BCa);
- the Mann-Whitney U test (``scipy.stats.mannwhitneyu``, two-sided): U is the novices' count of pairs
  in which the novice's value is the larger (a tie counts one half), over every novice-expert pair;
- Cliff's delta, the same number as the rank-biserial r: P(an expert does better than a novice) minus
  P(the novice does better), from -1 to 1, oriented by the metric's ``lower_is_better`` so that a
  positive value always means the experts do better; its 95 % CI by the two-sample bootstrap (each
  group resampled on its own, BCa). A metric whose CI reaches 0 does not separate the groups;
- Cohen's d (difference of the means over the pooled standard deviation, oriented the same way) with
  its bootstrap CI, for comparison with studies that report it;
- the contrasting-groups pass mark: a normal distribution is fitted to each group and the mark is
  where the two densities cross between the group means; its false-pass rate is the share of the
  fitted novices that would pass, its false-fail rate the share of fitted experts that would fail
  (and both as observed in the data).

Everything here is plain numbers in, plain numbers out; reading attempts and groups is
``chainsim.game.study.validity_data``, the files of a report ``chainsim.game.study.validity_report``.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

#: two-sided confidence of every interval
CONFIDENCE = 0.95
#: bootstrap resamples per interval (scipy's own default)
RESAMPLES = 9999
#: participants each group needs in a metric before it is analysed (a median, a spread and a rank test)
MIN_PER_GROUP = 3


@dataclass
class MetricResult:
    """What the analysis found for one metric; None where a figure could not be computed (``note`` says why)."""

    name: str
    label: str
    units: str
    lower_is_better: bool
    benchmark: float | None
    benchmark_source: str
    novice: np.ndarray
    expert: np.ndarray
    novice_median: float | None = None
    novice_ci: tuple[float, float] | None = None
    expert_median: float | None = None
    expert_ci: tuple[float, float] | None = None
    u: float | None = None
    p: float | None = None
    delta: float | None = None
    delta_ci: tuple[float, float] | None = None
    d: float | None = None
    d_ci: tuple[float, float] | None = None
    mark: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    #: what the pack's benchmark rests on ([metrics.NAME] benchmark_basis; a benchmark without one is provisional)
    benchmark_basis: str = "provisional"

    @property
    def separates(self) -> bool:
        """Whether the experts do better beyond chance: the CI of the effect lies above 0."""
        return self.delta_ci is not None and self.delta_ci[0] > 0


def _finite(values: Sequence[Any]) -> np.ndarray:
    return np.asarray([float(v) for v in values if v is not None and math.isfinite(float(v))], dtype=float)


def oriented_delta(novice: np.ndarray, expert: np.ndarray, lower_is_better: bool, axis: int = -1) -> np.ndarray:
    """Cliff's delta (= rank-biserial r), positive when the experts do better; vectorised along `axis`.

    From the midranks of both groups together: U = (novices' rank sum) - n1 (n1 + 1) / 2 counts the
    pairs with the novice larger (ties one half), and 2 U / (n1 n2) - 1 = P(novice larger) - P(smaller).
    """
    n1, n2 = novice.shape[axis], expert.shape[axis]
    ranks = stats.rankdata(np.concatenate([novice, expert], axis=axis), axis=axis)
    u = np.take(ranks, np.arange(n1), axis=axis).sum(axis=axis) - n1 * (n1 + 1) / 2
    larger = 2.0 * u / (n1 * n2) - 1.0
    return larger if lower_is_better else -larger


def oriented_d(novice: np.ndarray, expert: np.ndarray, lower_is_better: bool, axis: int = -1) -> np.ndarray:
    """Cohen's d with the pooled standard deviation, positive when the experts do better (NaN: no spread)."""
    n1, n2 = novice.shape[axis], expert.shape[axis]
    pooled = ((n1 - 1) * novice.var(axis=axis, ddof=1) + (n2 - 1) * expert.var(axis=axis, ddof=1)) / (n1 + n2 - 2)
    diff = novice.mean(axis=axis) - expert.mean(axis=axis)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(pooled > 0, diff / np.sqrt(np.where(pooled > 0, pooled, 1.0)), np.nan)
    return d if lower_is_better else -d


def bootstrap_ci(
    samples: tuple[np.ndarray, ...], statistic: Callable, rng: np.random.Generator, resamples: int = RESAMPLES
) -> tuple[float, float] | None:
    """The BCa bootstrap CI of `statistic` (vectorised, `axis` keyword), each sample resampled on its own.

    Values that never vary make every resample the same: the interval is that one value. Where BCa
    cannot be formed (its jackknife has no spread, as with heavily tied counts) the percentile interval
    is used; None when neither is a number (Cohen's d of two groups with no spread)."""
    if all(np.ptp(s) == 0 for s in samples):
        value = float(statistic(*samples, axis=-1))
        return (value, value) if math.isfinite(value) else None
    for method in ("BCa", "percentile"):
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")  # scipy's degenerate-data warnings: the NaN check below decides
            res = stats.bootstrap(
                samples,
                statistic,
                vectorized=True,
                paired=False,
                n_resamples=resamples,
                confidence_level=CONFIDENCE,
                method=method,
                rng=rng,
            )
        lo, hi = float(res.confidence_interval.low), float(res.confidence_interval.high)
        if math.isfinite(lo) and math.isfinite(hi):
            return lo, hi
    return None


def median_ci(values: np.ndarray, rng: np.random.Generator, resamples: int = RESAMPLES) -> tuple[float, float] | None:
    """A group's median and its bootstrap 95 % CI."""
    return bootstrap_ci((values,), lambda x, axis=-1: np.median(x, axis=axis), rng, resamples)


def mann_whitney(novice: np.ndarray, expert: np.ndarray) -> tuple[float, float]:
    """The novices' U and the two-sided p of the Mann-Whitney U test (scipy's exact or tie-corrected normal)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # all values tied: scipy warns, and p is 1
        res = stats.mannwhitneyu(novice, expert, alternative="two-sided")
    p = float(res.pvalue)
    return float(res.statistic), p if math.isfinite(p) else 1.0


def normal_crossing(m1: float, s1: float, m2: float, s2: float) -> float | None:
    """Where the densities of N(m1, s1) and N(m2, s2) cross between m1 and m2; None when they do not.

    Equal log-densities give a x^2 + b x + c = 0 (a = 0 when the spreads are equal: the midpoint)."""
    if s1 <= 0 or s2 <= 0 or m1 == m2:
        return None
    a = 1 / (2 * s2**2) - 1 / (2 * s1**2)
    b = m1 / s1**2 - m2 / s2**2
    c = m2**2 / (2 * s2**2) - m1**2 / (2 * s1**2) + math.log(s2 / s1)
    if abs(a) < 1e-12 * max(abs(b), 1e-300):
        roots = [-c / b]
    else:
        disc = b * b - 4 * a * c
        if disc < 0:
            return None
        q = -0.5 * (b + math.copysign(math.sqrt(disc), b))  # the stable form of the two roots
        roots = [q / a] + ([c / q] if q != 0 else [])
    lo, hi = min(m1, m2), max(m1, m2)
    inside = [r for r in roots if lo <= r <= hi]
    return min(inside, key=lambda r: abs(r - (m1 + m2) / 2)) if inside else None


def contrasting_groups(novice: np.ndarray, expert: np.ndarray, lower_is_better: bool) -> dict[str, Any]:
    """The contrasting-groups pass mark and its false-pass and false-fail rates (fitted and observed).

    A value passes at or below the mark (at or above it when higher is better). The mark needs the
    experts' mean to be the better one and both groups to vary; else `mark` is None and `why` says so."""
    mn, sn = float(novice.mean()), float(novice.std(ddof=1))
    me, se = float(expert.mean()), float(expert.std(ddof=1))
    out: dict[str, Any] = {"mark": None, "novice_fit": (mn, sn), "expert_fit": (me, se)}
    if not (me < mn if lower_is_better else me > mn):
        out["why"] = "the experts' mean is not the better one"
        return out
    if sn == 0 or se == 0:
        out["why"] = "a group's values do not vary, so no normal distribution can be fitted"
        return out
    mark = normal_crossing(mn, sn, me, se)
    if mark is None:
        out["why"] = "the fitted densities do not cross between the group means"
        return out
    passes = (lambda x: x <= mark) if lower_is_better else (lambda x: x >= mark)
    below_n, below_e = stats.norm.cdf(mark, mn, sn), stats.norm.cdf(mark, me, se)
    out.update(
        mark=mark,
        false_pass=float(below_n if lower_is_better else 1 - below_n),
        false_fail=float(1 - below_e if lower_is_better else below_e),
        observed_false_pass=float(np.mean(passes(novice))),
        observed_false_fail=float(1 - np.mean(passes(expert))),
    )
    return out


def analyse_metric(
    name: str,
    spec: dict[str, Any],
    novice_values: Sequence[Any],
    expert_values: Sequence[Any],
    *,
    rng: np.random.Generator,
    resamples: int = RESAMPLES,
) -> MetricResult:
    """Every statistic of one metric from the participants' values (None and non-finite values left out)."""
    lower = bool(spec.get("lower_is_better", True))
    bench = spec.get("benchmark")
    r = MetricResult(
        name=name,
        label=str(spec.get("label") or name),
        units=str(spec.get("units") or ""),
        lower_is_better=lower,
        benchmark=float(bench) if isinstance(bench, (int, float)) and not isinstance(bench, bool) else None,
        benchmark_source=str(spec.get("benchmark_source") or ""),
        benchmark_basis=str(spec.get("benchmark_basis") or "provisional"),
        novice=_finite(novice_values),
        expert=_finite(expert_values),
    )
    nov, exp = r.novice, r.expert
    if len(nov):
        r.novice_median, r.novice_ci = float(np.median(nov)), median_ci(nov, rng, resamples)
    if len(exp):
        r.expert_median, r.expert_ci = float(np.median(exp)), median_ci(exp, rng, resamples)
    if min(len(nov), len(exp)) < MIN_PER_GROUP:
        r.notes.append(
            f"too few participants with a value ({len(nov)} novices, {len(exp)} experts; "
            f"{MIN_PER_GROUP} per group needed)"
        )
        return r
    r.u, r.p = mann_whitney(nov, exp)
    delta = lambda n, e, axis=-1: oriented_delta(n, e, lower, axis)
    cohen = lambda n, e, axis=-1: oriented_d(n, e, lower, axis)
    r.delta = float(delta(nov, exp))
    r.delta_ci = bootstrap_ci((nov, exp), delta, rng, resamples)
    d = float(cohen(nov, exp))
    r.d = d if math.isfinite(d) else None
    r.d_ci = bootstrap_ci((nov, exp), cohen, rng, resamples) if r.d is not None else None
    r.mark = contrasting_groups(nov, exp, lower)
    if r.delta_ci is not None and r.delta_ci[1] < 0:
        r.notes.append("the novices do better than the experts on this metric")
    elif not r.separates:
        r.notes.append("does not separate the groups: the effect's CI covers 0")
    if r.mark.get("mark") is None:
        r.notes.append(f"no pass mark: {r.mark['why']}")
    return r


def curve_medians(series: Sequence[Sequence[float | None]]) -> list[float | None]:
    """The median over participants at each attempt number (from 1); None where no one has a value."""
    longest = max((len(s) for s in series), default=0)
    out: list[float | None] = []
    for k in range(longest):
        at_k = [float(v) for s in series if len(s) > k and (v := s[k]) is not None]
        out.append(float(np.median(at_k)) if at_k else None)
    return out

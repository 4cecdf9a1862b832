"""How far blinded raters agree, and how the simulator's metrics go with their judgement.

- **Inter-rater agreement**: the intraclass correlation for two-way random effects and absolute
  agreement (McGraw and Wong 1996, case 2A; Shrout and Fleiss 1979, ICC(2,1)): the raters are taken
  as a sample of the raters a programme could have, and a rater who marks every attempt two points
  higher disagrees. Reported for one rater, ICC(A,1), and for the mean of the k raters, ICC(A,k), each
  with its 95 % interval from the F distribution (scipy.stats.f) with Satterthwaite's degrees of
  freedom, as McGraw and Wong give it. The mean squares come from the two-way analysis of variance
  without replication (attempts x raters). Only attempts every rater has marked count (listwise).
- **Metric against judgement**: Spearman's rank correlation (scipy.stats.spearmanr) of each simulator
  metric with the raters' mean score over the same attempts, oriented so that a positive rho means
  the metric improves as the raters' judgement does (a lower-is-better metric is negated).

The arithmetic is checked against pingouin's intraclass_corr and Shrout and Fleiss's published example
(tests/unit/test_agreement.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import stats

from chainsim.systems.engine.errors import UserError


@dataclass(frozen=True, slots=True)
class Agreement:
    n: int  # attempts every rater marked
    k: int  # raters
    single: float  # ICC(A,1)
    single_ci: tuple[float, float]
    average: float  # ICC(A,k)
    average_ci: tuple[float, float]
    f: float  # between-attempts F
    df1: int
    df2: int
    p: float


def mean_squares(table: np.ndarray) -> tuple[float, float, float]:
    """(attempts, raters, residual) mean squares of an n x k table without replication."""
    n, k = table.shape
    grand = table.mean()
    ss_rows = k * float(((table.mean(axis=1) - grand) ** 2).sum())
    ss_cols = n * float(((table.mean(axis=0) - grand) ** 2).sum())
    ss_err = float(((table - grand) ** 2).sum()) - ss_rows - ss_cols
    return ss_rows / (n - 1), ss_cols / (k - 1), ss_err / ((n - 1) * (k - 1))


def icc(table) -> Agreement:
    """ICC(A,1) and ICC(A,k) with 95 % intervals for an attempts x raters table of scores."""
    t = np.asarray(table, dtype=np.float64)
    if t.ndim != 2 or t.shape[0] < 3 or t.shape[1] < 2:
        raise UserError(f"agreement needs at least 3 attempts marked by at least 2 raters each; got {t.shape}")
    n, k = t.shape
    msr, msc, mse = mean_squares(t)
    if mse == 0.0 and msr == 0.0:
        raise UserError("every rater gave every attempt the same score: agreement cannot be measured")
    single = (msr - mse) / (msr + (k - 1) * mse + k * (msc - mse) / n)
    spread = msr + (msc - mse) / n
    # the attempts differ by no more than the raters' noise: the mean of the raters agrees on nothing,
    # and the formula's limit is minus infinity (pingouin gives the same); the report says so in words
    average = (msr - mse) / spread if spread != 0.0 else -math.inf
    df1, df2 = n - 1, (n - 1) * (k - 1)
    f = msr / mse if mse > 0 else math.inf
    # McGraw and Wong (1996), case 2A: Satterthwaite's degrees of freedom v for the interval, written
    # with the raters' F (fj = msc / mse) and c = n (1 + (k - 1) single) - k single
    c = n * (1 + (k - 1) * single) - k * single
    if mse > 0:
        fj = msc / mse
        v = df2 * (k * single * fj + c) ** 2 / (df1 * (k * single * fj) ** 2 + c**2)
    elif msc > 0:  # no residual, raters apart by constants: the limit of v as fj grows
        v = df2 / df1
    else:  # every rater gave every attempt the same score as every other rater: perfect agreement
        return Agreement(n, k, 1.0, (1.0, 1.0), 1.0, (1.0, 1.0), math.inf, df1, df2, 0.0)
    fu, fl = stats.f.ppf(0.975, df1, v), stats.f.ppf(0.975, v, df1)
    low = n * (msr - fu * mse) / (fu * (k * msc + (k * n - k - n) * mse) + n * msr)
    high = n * (fl * msr - mse) / (k * msc + (k * n - k - n) * mse + n * fl * msr)
    return Agreement(
        n=n,
        k=k,
        single=float(single),
        single_ci=(float(low), float(high)),
        average=float(average),
        average_ci=(float(low * k / (1 + low * (k - 1))), float(high * k / (1 + high * (k - 1)))),
        f=float(f),
        df1=df1,
        df2=df2,
        p=float(stats.f.sf(f, df1, df2)),
    )


def complete(rows: list[dict], raters: list[str]) -> tuple[np.ndarray, list[dict]]:
    """The attempts x raters table of the rows every rater marked, and those rows."""
    full = [r for r in rows if all(r["scores"].get(name) is not None for name in raters)]
    return np.array([[float(r["scores"][name]) for name in raters] for r in full]).reshape(len(full), len(raters)), full


def metric_correlations(rows: list[dict], metrics: dict[str, dict], specs: dict[str, dict]) -> list[dict]:
    """Per metric: Spearman's rho with the raters' mean score (oriented: positive, the metric better as
    judged better), its p value and the attempts it rests on. `metrics`: attempt id -> {metric: value}."""
    out = []
    for name, spec in specs.items():
        pairs = []
        for r in rows:
            v = (metrics.get(r["attempt_id"]) or {}).get(name)
            marks = [s for s in r["scores"].values() if s is not None]
            if v is not None and math.isfinite(float(v)) and marks:
                sign = -1.0 if spec.get("lower_is_better", True) else 1.0
                pairs.append((sign * float(v), float(np.mean(marks))))
        row = {"metric": name, "label": spec.get("label") or name, "n": len(pairs), "rho": None, "p": None}
        if len(pairs) >= 3 and len({x for x, _ in pairs}) > 1 and len({y for _, y in pairs}) > 1:
            res = stats.spearmanr([x for x, _ in pairs], [y for _, y in pairs])
            row["rho"], row["p"] = float(res.statistic), float(res.pvalue)
        out.append(row)
    return out

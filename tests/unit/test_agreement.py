"""The agreement statistics of a blinded rating against a reference written elsewhere: pingouin's intraclass_corr on
random tables (hypothesis draws the scores), Shrout and Fleiss's (1979) published example, and what agreement means
(raters who agree perfectly give 1, raters who mark at random give about 0); Spearman's rho oriented by the metric."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pingouin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from chainsim.game.study import agreement as A
from chainsim.systems.engine.errors import UserError

#: Shrout and Fleiss (1979), Table 2: six targets, four judges
SHROUT_FLEISS = np.array([[9, 2, 5, 8], [6, 1, 3, 2], [8, 4, 6, 8], [7, 1, 2, 6], [10, 5, 6, 9], [6, 2, 4, 7]])


def _reference(table: np.ndarray):
    n, k = table.shape
    long = pd.DataFrame(
        {"t": np.repeat(np.arange(n), k), "r": np.tile(np.arange(k), n), "s": table.ravel().astype(float)}
    )
    res = pingouin.intraclass_corr(long, targets="t", raters="r", ratings="s").set_index("Type")
    return res.loc["ICC(A,1)"], res.loc["ICC(A,k)"]


@settings(max_examples=60, deadline=None)
@given(
    st.integers(3, 12).flatmap(
        lambda n: st.integers(2, 5).flatmap(lambda k: arrays(np.int64, (n, k), elements=st.integers(5, 25)))
    )
)
def test_icc_matches_pingouin_on_drawn_tables(table):
    if np.ptp(table) == 0:
        with pytest.raises(UserError):
            A.icc(table)
        return
    ours = A.icc(table)
    one, avg = _reference(table)
    assert ours.single == pytest.approx(one["ICC"], abs=1e-6, nan_ok=True)
    assert ours.average == pytest.approx(avg["ICC"], abs=1e-6, nan_ok=True)
    assert ours.f == pytest.approx(one["F"], rel=1e-6, nan_ok=True) and ours.df2 == one["df2"]
    assert ours.p == pytest.approx(one["pval"], abs=1e-6, nan_ok=True)
    _, msc, mse = A.mean_squares(table.astype(float))
    if mse == 0.0 and msc == 0.0:  # raters identical: perfect agreement, where pingouin's interval divides by 0
        assert ours.single_ci == ours.average_ci == (1.0, 1.0) and ours.single == ours.average == 1.0
        return
    for got, want in ((ours.single_ci, one["CI95"]), (ours.average_ci, avg["CI95"])):
        # pingouin rounds its interval to 2 places
        assert np.allclose(got, want, atol=0.005 + 1e-9, equal_nan=True)


def test_shrout_and_fleiss_published_example():
    a = A.icc(SHROUT_FLEISS)
    assert round(a.single, 2) == 0.29 and round(a.average, 2) == 0.62  # their Table 4: ICC(2,1), ICC(2,4)
    assert a.n == 6 and a.k == 4 and a.df1 == 5 and a.df2 == 15


def test_agreeing_raters_give_one_and_random_raters_about_zero():
    rng = np.random.default_rng(7)
    truth = rng.integers(5, 26, size=40).astype(float)
    same = A.icc(np.column_stack([truth, truth, truth]))
    assert same.single == pytest.approx(1.0) and same.single_ci[0] > 0.95
    noise = A.icc(rng.integers(5, 26, size=(40, 3)))
    assert abs(noise.single) < 0.2 and noise.single_ci[0] < 0.0 < noise.single_ci[1]
    shifted = A.icc(np.column_stack([truth, truth + 3.0]))  # one rater marks everything 3 higher
    assert shifted.single < 1.0  # absolute agreement: a constant offset is disagreement


def test_raters_who_differ_more_than_the_attempts_give_no_mean_agreement():
    a = A.icc([[8, 5], [5, 8], [5, 5]])  # the attempts' mean square equals the residual's over n
    assert a.single == pytest.approx(-1.0) and a.average == -np.inf


def test_too_few_attempts_or_raters_is_one_line():
    with pytest.raises(UserError, match="at least 3 attempts marked by at least 2 raters"):
        A.icc(np.ones((2, 3)))


def test_metric_correlation_is_oriented_by_the_metric():
    rows = [{"attempt_id": i, "scores": {"a": 25 - 2 * i, "b": 24 - 2 * i}} for i in range(6)]
    metrics = {i: {"error_mm": 1.0 + i, "ok": 10.0 - i} for i in range(6)}
    specs = {"error_mm": {"label": "Error"}, "ok": {"lower_is_better": False}, "none": {}}
    out = {r["metric"]: r for r in A.metric_correlations(rows, metrics, specs)}
    assert out["error_mm"]["rho"] == pytest.approx(1.0) and out["ok"]["rho"] == pytest.approx(1.0)
    assert out["none"]["rho"] is None and out["none"]["n"] == 0

"""The validity statistics on synthetic cohorts whose truth is known: the effect's interval covers the
constructed effect as often as a 95 % interval should, one source gives no difference, the
contrasting-groups mark lands where the constructed densities cross, and U is the plain pair count."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import optimize, stats

from chainsim.game.study import cohort, validity, validity_report
from chainsim.game.study.cohort import Draw
from chainsim.game.study.validity_data import select

METRICS = {"m": {"label": "M", "units": "u", "lower_is_better": True}}
SEEDS = 1000
RESAMPLES = 2000
#: a seed-count's allowance around a 95 % rate: three binomial standard errors
ALLOW = 3 * math.sqrt(0.95 * 0.05 / SEEDS)


def groups(drawn) -> tuple[np.ndarray, np.ndarray]:
    by = {"novice": [], "expert": []}
    for _trainee, record in drawn:
        by[record["details"]["protocol"]["group"]].append(record["metrics"]["m"])
    return np.asarray(by["novice"]), np.asarray(by["expert"])


def reference_u(x, y) -> float:
    """The Mann-Whitney U of x by its definition: pairs with x's value larger, a tie counting one half."""
    return sum(1.0 if a > b else 0.5 if a == b else 0.0 for a in x for b in y)


def test_the_effects_interval_covers_the_constructed_effect_of_d_08_with_36_participants():
    # two normal groups of one spread d apart: Cliff's delta = P(X > Y) - P(X < Y) = 2 Phi(d / sqrt 2) - 1
    truth = 2 * stats.norm.cdf(0.8 / math.sqrt(2)) - 1
    covered, widths = 0, []
    delta = lambda n, e, axis=-1: validity.oriented_delta(n, e, True, axis)
    for seed in range(SEEDS):
        nov, exp = groups(cohort.build(METRICS, 36, pack="p", effect=0.8, seed=seed))
        assert len(nov) == len(exp) == 18
        lo, hi = validity.bootstrap_ci((nov, exp), delta, np.random.default_rng(seed), RESAMPLES)
        covered += lo <= truth <= hi
        widths.append(hi - lo)
    rate = covered / SEEDS
    # a 95 % interval covers in 95 % of seeds give or take the seeds' own binomial spread (0.7 % at 1000)
    assert 0.95 - ALLOW <= rate <= 0.99, rate
    assert np.median(widths) < 0.8  # an interval that says nothing (all of -1..1) would cover every time


def test_groups_from_one_source_show_no_difference_about_95_percent_of_the_time():
    reported = tested = flagged = 0
    seeds = 200
    for seed in range(seeds):
        drawn = cohort.build(METRICS, 36, pack="p", effect=0.0, seed=seed)
        sel = select(cohort.as_listed(drawn), None, pack="p")
        r = validity_report.analyse(sel, METRICS, pack="p", source="test", seed=seed, resamples=RESAMPLES).results[0]
        lo, hi = r.delta_ci
        reported += not lo <= 0 <= hi
        tested += r.p < 0.05
        flagged += not r.separates
    allow = 3 * math.sqrt(0.05 * 0.95 / seeds)
    assert 0.05 - allow <= reported / seeds <= 0.05 + allow, reported
    assert 0.05 - allow <= tested / seeds <= 0.05 + allow, tested
    assert flagged / seeds >= 0.9


def test_the_contrasting_groups_mark_is_where_the_constructed_densities_cross():
    draw = Draw(novice_mean=10.0, novice_sd=2.0, expert_mean=5.0, expert_sd=1.0)
    crossing = optimize.brentq(lambda x: stats.norm.pdf(x, 10, 2) - stats.norm.pdf(x, 5, 1), 5, 10)
    nov, exp = groups(cohort.build(METRICS, 2000, pack="p", draws={"m": draw}, seed=7))
    m = validity.contrasting_groups(nov, exp, lower_is_better=True)
    # 1000 a group: the fitted mark's spread is 0.04 (50 seeds)
    assert m["mark"] == pytest.approx(crossing, abs=0.15)
    assert m["false_pass"] == pytest.approx(stats.norm.cdf(crossing, 10, 2), abs=0.02)
    assert m["false_fail"] == pytest.approx(stats.norm.sf(crossing, 5, 1), abs=0.01)
    assert m["observed_false_pass"] == pytest.approx(np.mean(nov <= m["mark"]))
    assert m["observed_false_fail"] == pytest.approx(np.mean(exp > m["mark"]))


def test_when_higher_is_better_the_experts_are_above_and_the_mark_passes_upwards():
    metrics = {"m": {"label": "M", "lower_is_better": False}}
    draw = Draw(novice_mean=50.0, novice_sd=5.0, expert_mean=70.0, expert_sd=5.0)
    nov, exp = groups(cohort.build(metrics, 400, pack="p", draws={"m": draw}, seed=3))
    r = validity.analyse_metric("m", metrics["m"], nov, exp, rng=np.random.default_rng(0), resamples=RESAMPLES)
    assert r.delta > 0.9 and r.separates and r.d > 3
    assert r.mark["mark"] == pytest.approx(60.0, abs=1.0)  # equal spreads: the midpoint
    assert r.mark["observed_false_pass"] == pytest.approx(np.mean(nov >= r.mark["mark"]))
    # the same values read as lower-is-better: the experts do worse, the effect is negative and no mark is set
    flipped = validity.analyse_metric("m", {}, nov, exp, rng=np.random.default_rng(0), resamples=RESAMPLES)
    assert flipped.delta < -0.9 and not flipped.separates and flipped.mark["mark"] is None
    assert any("novices do better" in n for n in flipped.notes)


@pytest.mark.parametrize(
    ("m1", "s1", "m2", "s2"), [(10, 2, 5, 1), (0, 1, 3, 1), (1, 0.5, 4, 3), (-2, 1, 1.5, 1.2), (100, 40, 20, 5)]
)
def test_normal_crossing_is_the_root_between_the_means(m1, s1, m2, s2):
    x = validity.normal_crossing(m1, s1, m2, s2)
    root = optimize.brentq(lambda t: stats.norm.pdf(t, m1, s1) - stats.norm.pdf(t, m2, s2), min(m1, m2), max(m1, m2))
    assert x == pytest.approx(root, abs=1e-9)


def test_no_crossing_between_the_means_gives_no_mark():
    # a wide group and a narrow one whose density is the higher at both means
    assert validity.normal_crossing(0.0, 10.0, 1.0, 1.0) is None
    nov = np.array([3.0, 3.0, 3.0])
    assert validity.contrasting_groups(nov, np.array([1.0, 2.0, 1.5]), True)["mark"] is None


values = st.lists(
    st.one_of(st.integers(0, 5).map(float), st.floats(-1e3, 1e3, allow_nan=False)), min_size=1, max_size=25
)


@settings(max_examples=200, deadline=None)
@given(values, values)
def test_u_and_cliffs_delta_agree_with_the_plain_pair_count(x, y):
    u, p = validity.mann_whitney(np.asarray(x), np.asarray(y))
    ref = reference_u(x, y)
    assert u == pytest.approx(ref, abs=1e-6)
    assert 0.0 <= p <= 1.0
    delta = float(validity.oriented_delta(np.asarray(x), np.asarray(y), lower_is_better=True))
    assert delta == pytest.approx(2 * ref / (len(x) * len(y)) - 1, abs=1e-9)


def test_the_reports_u_is_the_novices_pair_count():
    drawn = cohort.build(METRICS, 12, pack="p", effect=0.8, trials=3, seed=1, learning=1.0, trial_sd=0.3)
    sel = select(cohort.as_listed(drawn), None, pack="p")
    r = validity_report.analyse(sel, METRICS, pack="p", source="test", resamples=RESAMPLES).results[0]
    per = {}
    for name, own in sel.series.items():  # each participant's median over their three attempts
        per.setdefault(sel.participants[name].group, []).append(float(np.median([a["metrics"]["m"] for a in own])))
    assert r.u == pytest.approx(reference_u(per["novice"], per["expert"]), abs=1e-6)
    assert sorted(r.novice) == pytest.approx(sorted(per["novice"]))


def test_values_that_never_vary_give_a_point_interval_and_no_normal_fit():
    rng = np.random.default_rng(0)
    nov, exp = np.array([2.0, 3.0, 3.0, 4.0]), np.array([0.0, 0.0, 0.0, 0.0])
    r = validity.analyse_metric("m", {}, nov, exp, rng=rng, resamples=RESAMPLES)
    assert r.expert_ci == (0.0, 0.0) and r.delta == 1.0 and r.separates
    assert r.mark["mark"] is None and "do not vary" in r.mark["why"]


def test_too_few_participants_are_not_tested():
    r = validity.analyse_metric("m", {}, [1.0, 2.0], [0.5, None, 0.7], rng=np.random.default_rng(0), resamples=1000)
    assert r.u is None and r.delta_ci is None and not r.separates
    assert "too few participants" in r.notes[0] and len(r.expert) == 2

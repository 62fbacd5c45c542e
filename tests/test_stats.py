"""Success-rate intervals and bootstrap aggregates, on hand-made records with known answers."""

import math

import numpy as np
import pytest

from softpend.stats import aggregate_interval, iqm, wilson_interval


@pytest.mark.parametrize(
    "k, n, low, high",
    [
        (8, 10, 0.4902, 0.9433),  # Wilson (1927) score interval, z = 1.95996
        (0, 10, 0.0, 0.2775),
        (10, 10, 0.7225, 1.0),
        (20, 20, 0.8389, 1.0),
        (1, 2, 0.0945, 0.9055),
    ],
)
def test_wilson_interval_matches_the_closed_form(k, n, low, high):
    got = wilson_interval(k, n)
    assert got == pytest.approx((low, high), abs=1e-4)


def test_wilson_interval_narrows_with_more_trials_and_lower_confidence():
    assert np.diff(wilson_interval(18, 20))[0] < np.diff(wilson_interval(9, 10))[0]
    assert np.diff(wilson_interval(9, 10, 0.8))[0] < np.diff(wilson_interval(9, 10, 0.95))[0]


@pytest.mark.parametrize("args", [(3, 0), (11, 10), (-1, 10), (2.5, 10), (True, 10), (1, 10, 1.0), (1, 10, 0.0)])
def test_wilson_interval_rejects_impossible_counts(args):
    with pytest.raises(ValueError):
        wilson_interval(*args)


def test_iqm_is_the_mean_of_the_middle_half():
    assert iqm(np.arange(1, 11)) == pytest.approx(np.mean(np.arange(3, 9)))  # 10 values: 2 cut from each end
    assert iqm([1, 2, 3, 1000.0]) == pytest.approx(2.5)  # the outlier does not move it
    assert math.isinf(iqm([1.0, math.inf, math.inf, math.inf]))


def test_aggregate_interval_contains_the_estimate_and_is_reproducible():
    scores = np.array([60, 75, 80, 85, 95, 100, 120, 150, 175, 400.0])
    a = aggregate_interval(scores, "iqm", seed=1)
    b = aggregate_interval(scores, "iqm", seed=1)
    assert a == b
    assert a.low <= a.value <= a.high and a.value == pytest.approx(iqm(scores))
    assert scores.min() <= a.low < a.high <= scores.max()
    m = aggregate_interval(scores, "median", seed=1)
    assert m.value == pytest.approx(97.5) and m.low <= 97.5 <= m.high
    assert aggregate_interval(scores, "iqm", seed=2) != a  # another seed, other resamples


def test_the_bootstrap_is_stratified_by_task():
    """Task A scores are all 0, task B all 100: every stratified resample holds half of each, so the median
    is always 50 (resampling runs across tasks would give 0 or 100 in some resamples)."""
    scores = np.column_stack([np.zeros(6), np.full(6, 100.0)])
    result = aggregate_interval(scores, "median", seed=0)
    assert (result.low, result.value, result.high) == (50.0, 50.0, 50.0)


def test_runs_that_never_got_there_count_as_the_largest():
    scores = np.array([50, 60, 70, 80, math.inf, math.inf, math.inf, math.inf, math.inf, math.inf])
    result = aggregate_interval(scores, "median", seed=0)
    assert math.isinf(result.value) and math.isinf(result.high)


@pytest.mark.parametrize("scores, statistic", [([1.0], "iqm"), ([1.0, float("nan")], "iqm"), ([1.0, 2.0], "mean")])
def test_aggregate_interval_rejects_bad_input(scores, statistic):
    with pytest.raises(ValueError):
        aggregate_interval(scores, statistic)

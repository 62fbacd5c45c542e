"""Statistics of results over seeds and starts: intervals for success rates and aggregates of runs."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import scipy.stats

from softpend.checks import in_unit_interval, int_at_least


def wilson_interval(successes: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval ``(low, high)`` of a success probability from ``successes`` of ``trials``."""
    n = float(int_at_least("trials", trials, 1))
    if int_at_least("successes", successes, 0) > trials:
        raise ValueError(f"successes must be an integer in [0, trials={trials}], got {successes!r}")
    in_unit_interval("confidence", confidence, include_zero=False, include_one=False)
    p = successes / n
    z = float(scipy.stats.norm.ppf(0.5 + confidence / 2.0))
    denominator = 1.0 + z**2 / n
    centre = (p + z**2 / (2 * n)) / denominator
    half = z * math.sqrt(p * (1.0 - p) / n + z**2 / (4 * n**2)) / denominator
    return max(0.0, centre - half), min(1.0, centre + half)


def iqm(values: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """Interquartile mean: the mean of the values between the 25th and 75th percentile (25 % trimmed from
    each end, :func:`scipy.stats.trim_mean`); ``inf`` values count as the largest."""
    values = np.asarray(values, dtype=float)
    if axis is None:
        values, axis = values.reshape(-1), 0
    return scipy.stats.trim_mean(values, 0.25, axis=axis)


#: The aggregates of :func:`aggregate_interval` (``inf`` values count as the largest).
AGGREGATES: dict[str, Callable[..., np.ndarray | float]] = {"median": np.median, "iqm": iqm}


@dataclass(frozen=True)
class AggregateInterval:
    """An aggregate of per-run scores with its bootstrap confidence interval."""

    value: float
    low: float
    high: float


def aggregate_interval(
    scores: Sequence[float] | np.ndarray,
    statistic: str = "iqm",
    confidence: float = 0.95,
    n_resamples: int = 2000,
    seed: int = 0,
) -> AggregateInterval:
    """Point estimate and stratified bootstrap interval of ``statistic`` over runs."""
    if statistic not in AGGREGATES:
        raise ValueError(f"statistic must be one of {sorted(AGGREGATES)}, got {statistic!r}")
    data = np.asarray(scores, dtype=float)
    if data.ndim == 1:
        data = data[:, None]
    if data.ndim != 2 or data.shape[0] < 2 or data.shape[1] < 1:
        raise ValueError(f"scores must have shape (n_runs >= 2,) or (n_runs >= 2, n_tasks), got {np.shape(scores)}")
    if np.isnan(data).any():
        raise ValueError("scores must not contain NaN")
    in_unit_interval("confidence", confidence, include_zero=False, include_one=False)
    int_at_least("n_resamples", n_resamples, 100)
    aggregate = AGGREGATES[statistic]
    value = float(aggregate(data))

    def stratified(*columns: np.ndarray, axis: int = -1) -> np.ndarray | float:
        return aggregate(np.concatenate(columns, axis=axis), axis=axis)

    if np.all(data == data.flat[0]):  # every resample gives the same value; scipy would warn about it
        low = high = value
    else:
        with np.errstate(invalid="ignore"):
            result = scipy.stats.bootstrap(
                list(data.T),
                stratified,
                n_resamples=int(n_resamples),
                confidence_level=confidence,
                method="percentile",
                vectorized=True,
                rng=np.random.default_rng(seed),
            )
        low, high = float(result.confidence_interval.low), float(result.confidence_interval.high)
    return AggregateInterval(value, low, high)

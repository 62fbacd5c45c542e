"""Learning curves in plant time, and when a run "reaches its asymptotic reward".

The report's Figure 4 plots the episode return against training episodes for both methods and reads off
the episode after which the curve stops rising ("reaching the asymptotic reward in approximately 150
episodes").  We make that reading precise (:func:`episodes_to_asymptote`):

* smooth the per-episode return with a trailing moving average of ``window`` episodes;
* the *asymptotic reward* is the mean return over the last ``final_fraction`` of the run;
* the run *reaches* it at the first episode after which the smoothed return stays at or above
  ``start + level * (asymptote - start)`` for the rest of the run (``start`` = the first smoothed value,
  ``level = 0.9``), i.e. it has covered 90 % of its total improvement and does not fall back.

Curves of several seeds are put on a common axis (episodes, or real plant seconds) and summarised by an
aggregate over seeds (the interquartile mean) with its stratified bootstrap interval in :func:`interval_band`.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from softpend.checks import in_unit_interval, positive_int
from softpend.evaluation import SUCCESS_STD_RAD
from softpend.rl.training_log import TrainingLog

__all__ = [
    "moving_average",
    "episodes_to_asymptote",
    "run_to_asymptote",
    "failures_as",
    "interval_band",
    "plant_s_at_episode",
    "worst_start_std_rad",
]


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average (the first ``window - 1`` entries average what is there)."""
    values = np.asarray(values, dtype=float)
    window = positive_int("window", window)
    csum = np.cumsum(np.insert(values, 0, 0.0))
    n = np.arange(1, len(values) + 1)
    lo = np.maximum(0, n - window)
    return (csum[n] - csum[lo]) / (n - lo)


def episodes_to_asymptote(
    returns: Sequence[float] | np.ndarray, window: int = 10, level: float = 0.9, final_fraction: float = 0.2
) -> float:
    """Episode (1-based) at which a return curve reaches its asymptotic reward (see the module docstring).

    Returns ``inf`` for an empty curve; a curve that never improves reaches it at episode 1.
    """
    r = np.asarray(returns, dtype=float)
    if r.ndim != 1:
        raise ValueError(f"returns must be 1-D, got shape {r.shape}")
    in_unit_interval("level", level, include_zero=False)
    in_unit_interval("final_fraction", final_fraction, include_zero=False)
    if len(r) == 0:
        return math.inf
    smooth = moving_average(r, window)
    n_final = max(1, int(math.ceil(final_fraction * len(r))))
    asymptote = float(np.mean(r[-n_final:]))
    start = float(smooth[min(window, len(r)) - 1]) if len(r) >= window else float(smooth[0])
    if asymptote <= start:
        return 1.0
    threshold = start + level * (asymptote - start)
    below = np.flatnonzero(smooth < threshold)
    if len(below) == 0:
        return 1.0
    last_below = int(below[-1])
    return float(last_below + 2) if last_below + 1 < len(r) else math.inf


def run_to_asymptote(log: TrainingLog, window: int = 10) -> tuple[float, float]:
    """``(episodes, plant seconds)`` at which one training run reaches its asymptotic reward.

    A run trained to the end of its budget: the curve reading of :func:`episodes_to_asymptote`.  A run that its
    stop rule ended (``log.stop_reason`` set: its agent balanced the selection starts and training stopped) has no
    tail from which to read an asymptote; its agent no longer changes after the stop, so it reaches its asymptotic
    performance at the stop episode: ``(log.n_episodes, log.plant_s)``.
    """
    if log.stop_reason is not None and log.n_episodes > 0:
        return float(log.n_episodes), float(log.plant_s)
    episodes = episodes_to_asymptote(log.column("return"), window=window)
    return episodes, plant_s_at_episode(log, episodes)


def failures_as(
    values: Sequence[float] | np.ndarray, success_rates: Sequence[float] | np.ndarray, failed_as: float
) -> np.ndarray:
    """``values`` with ``failed_as`` in place of every entry whose success rate is below 1 (some start failed).

    For the worst evaluation start's upright std with ``failed_as`` the success level: exact where every start
    succeeded, and an evaluation that stopped at its first failing start
    (:attr:`softpend.rl.DQNConfig.eval_until_first_failure`) does not need the starts it did not run.
    """
    return np.where(np.asarray(success_rates, dtype=float) < 1.0, float(failed_as), np.asarray(values, dtype=float))


def worst_start_std_rad(log: TrainingLog, failed_as: float = SUCCESS_STD_RAD) -> np.ndarray:
    """Per evaluation row: the worst start's upright std [rad], or ``failed_as`` where a start failed
    (:func:`failures_as`)."""
    return failures_as(
        log.column("max_upright_std_rad", "evaluations"), log.column("success_rate", "evaluations"), failed_as
    )


def plant_s_at_episode(log: TrainingLog, episode: float) -> float:
    """Real plant seconds consumed when ``episode`` (1-based) ended (``inf`` for ``inf``)."""
    if math.isinf(episode):
        return math.inf
    return float(log.episodes[int(episode) - 1]["plant_s"])


def interval_band(
    logs: Sequence[TrainingLog],
    field: str = "max_upright_std_rad",
    axis: str = "plant_s",
    grid: np.ndarray | None = None,
    table: str = "evaluations",
    statistic: str = "iqm",
    confidence: float = 0.95,
    n_resamples: int = 1000,
    seed: int = 0,
    failed_as: float | None = None,
) -> dict[str, np.ndarray]:
    """An aggregate over seeds of one logged quantity with its bootstrap interval at every point of a common axis.

    A run that ended before the end of ``grid`` (its budget was smaller, or training stopped early because it
    balanced) keeps its last row's value from there on: its agent no longer changes.  Points before a run's
    first row are left out of the grid.

    Parameters
    ----------
    logs : sequence of TrainingLog
        One per seed, at least two.
    field, axis, table : str
        As :func:`aggregate`.
    grid : array, optional
        x values (default: 200 points from the latest first row to the furthest last row).
    statistic : {"iqm", "median"}
        Aggregate over seeds (:func:`softpend.stats.aggregate_interval`).
    confidence, n_resamples, seed
        Of the percentile bootstrap over seeds at every point.
    failed_as : float, optional
        The value of every row whose ``success_rate`` is below 1 (some start failed; :func:`failures_as`).

    Returns
    -------
    dict with ``x``, ``value``, ``low``, ``high`` and ``per_seed`` (n_seeds, len(x)); ``inf`` values (a run
    that never swung up) count as the largest.
    """
    from softpend.stats import aggregate_interval

    if len(logs) < 2:
        raise ValueError(f"interval_band needs at least two runs, got {len(logs)}")
    if axis not in ("episode", "plant_s"):
        raise ValueError(f"axis must be 'episode' or 'plant_s', got {axis!r}")
    xs = [log.column(axis, table) for log in logs]
    ys = [log.column(field, table) for log in logs]
    if failed_as is not None:
        ys = [failures_as(y, log.column("success_rate", table), failed_as) for log, y in zip(logs, ys)]
    if any(len(x) == 0 for x in xs):
        raise ValueError(f"every run needs at least one {table} row")
    if grid is None:
        grid = np.linspace(max(x[0] for x in xs), max(x[-1] for x in xs), 200)
    grid = np.asarray(grid, dtype=float)
    grid = grid[grid >= max(x[0] for x in xs)]
    per_seed = np.empty((len(logs), len(grid)))
    for i, (x, y) in enumerate(zip(xs, ys)):
        # a step function: the value of the latest row at or before each grid point
        index = np.searchsorted(x, grid, side="right") - 1
        per_seed[i] = y[np.clip(index, 0, len(y) - 1)]
    value, low, high = np.empty(len(grid)), np.empty(len(grid)), np.empty(len(grid))
    for j in range(len(grid)):
        interval = aggregate_interval(
            per_seed[:, j], statistic, confidence=confidence, n_resamples=n_resamples, seed=seed
        )
        value[j], low[j], high[j] = interval.value, interval.low, interval.high
    return {"x": grid, "value": value, "low": low, "high": high, "per_seed": per_seed}

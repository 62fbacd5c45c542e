"""Learning curves in plant time, and when a run "reaches its asymptotic reward"."""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from softpend.checks import one_of, positive_int
from softpend.evaluation import SUCCESS_STD_RAD
from softpend.rl.training_log import TrainingLog


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average (the first ``window - 1`` entries average what is there)."""
    values = np.asarray(values, dtype=float)
    window = positive_int("window", window)
    csum = np.cumsum(np.insert(values, 0, 0.0))
    n = np.arange(1, len(values) + 1)
    lo = np.maximum(0, n - window)
    return (csum[n] - csum[lo]) / (n - lo)


def episodes_to_asymptote(returns: Sequence[float] | np.ndarray, window: int = 10) -> float:
    """Episode (1-based) at which a return curve reaches 90 % of the way from its start to its asymptotic reward, the
    mean of its final 20 % (see the module docstring)."""
    r, level = np.asarray(returns, dtype=float), 0.9
    if r.ndim != 1:
        raise ValueError(f"returns must be 1-D, got shape {r.shape}")
    if len(r) == 0:
        return math.inf
    smooth = moving_average(r, window)
    n_final = max(1, int(math.ceil(0.2 * len(r))))
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
    """``(episodes, plant seconds)`` at which one training run reaches its asymptotic reward."""
    if log.stop_reason is not None and log.n_episodes > 0:
        return float(log.n_episodes), float(log.plant_s)
    episodes = episodes_to_asymptote(log.column("return"), window=window)
    return episodes, math.inf if math.isinf(episodes) else float(log.episodes[int(episodes) - 1]["plant_s"])


def failures_as(
    values: Sequence[float] | np.ndarray, success_rates: Sequence[float] | np.ndarray, failed_as: float
) -> np.ndarray:
    """``values`` with ``failed_as`` in place of every entry whose success rate is below 1 (some start failed)."""
    return np.where(np.asarray(success_rates, dtype=float) < 1.0, float(failed_as), np.asarray(values, dtype=float))


def worst_start_std_rad(log: TrainingLog, failed_as: float = SUCCESS_STD_RAD) -> np.ndarray:
    """Per evaluation row: the worst start's upright std [rad], or ``failed_as`` where a start failed
    (:func:`failures_as`)."""
    return failures_as(
        log.column("max_upright_std_rad", "evaluations"), log.column("success_rate", "evaluations"), failed_as
    )


def interval_band(
    logs: Sequence[TrainingLog],
    field: str = "max_upright_std_rad",
    axis: str = "plant_s",
    grid: np.ndarray | None = None,
    n_resamples: int = 1000,
    seed: int = 0,
    failed_as: float | None = None,
) -> dict[str, np.ndarray]:
    """The IQM over seeds of one evaluation field with its 95 % bootstrap interval at every point of a common axis."""
    from softpend.stats import aggregate_interval

    if len(logs) < 2:
        raise ValueError(f"interval_band needs at least two runs, got {len(logs)}")
    one_of("axis", axis, ("episode", "plant_s"))
    xs = [log.column(axis, "evaluations") for log in logs]
    ys = [log.column(field, "evaluations") for log in logs]
    if failed_as is not None:
        ys = [failures_as(y, log.column("success_rate", "evaluations"), failed_as) for log, y in zip(logs, ys)]
    if any(len(x) == 0 for x in xs):
        raise ValueError("every run needs at least one evaluation row")
    if grid is None:
        grid = np.linspace(max(x[0] for x in xs), max(x[-1] for x in xs), 200)
    grid = np.asarray(grid, dtype=float)[np.asarray(grid) >= max(x[0] for x in xs)]
    per_seed = np.empty((len(logs), len(grid)))
    for i, (x, y) in enumerate(zip(xs, ys)):
        # a step function: the value of the latest row at or before each grid point
        index = np.searchsorted(x, grid, side="right") - 1
        per_seed[i] = y[np.clip(index, 0, len(y) - 1)]
    intervals = [aggregate_interval(column, "iqm", 0.95, n_resamples, seed) for column in per_seed.T]
    band = {name: np.array([getattr(i, name) for i in intervals], dtype=float) for name in ("value", "low", "high")}
    return {"x": grid, **band, "per_seed": per_seed}

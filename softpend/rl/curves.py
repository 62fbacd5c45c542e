"""Learning curves in plant time, and when a run "reaches its asymptotic reward".

The report's Figure 4 plots the episode return against training episodes for both methods and reads off
the episode after which the curve stops rising ("reaching the asymptotic reward in approximately 150
episodes").  We make that reading precise (:func:`episodes_to_asymptote`):

* smooth the per-episode return with a trailing moving average of ``window`` episodes;
* the *asymptotic reward* is the mean return over the last ``final_fraction`` of the run;
* the run *reaches* it at the first episode after which the smoothed return stays at or above
  ``start + level * (asymptote - start)`` for the rest of the run (``start`` = the first smoothed value,
  ``level = 0.9``), i.e. it has covered 90 % of its total improvement and does not fall back.

Curves of several seeds are put on a common axis (episodes, or real plant seconds by interpolation) and
summarised by their mean and spread (min-max) in :func:`aggregate`.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from softpend.checks import in_unit_interval, positive_int
from softpend.rl.training_log import TrainingLog

__all__ = ["moving_average", "episodes_to_asymptote", "aggregate", "plant_s_at_episode"]


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing moving average (the first ``window - 1`` entries average what is there)."""
    values = np.asarray(values, dtype=float)
    window = positive_int("window", window)
    csum = np.cumsum(np.insert(values, 0, 0.0))
    n = np.arange(1, len(values) + 1)
    lo = np.maximum(0, n - window)
    return (csum[n] - csum[lo]) / (n - lo)


def episodes_to_asymptote(returns: Sequence[float], window: int = 10, level: float = 0.9, final_fraction: float = 0.2) -> float:
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


def plant_s_at_episode(log: TrainingLog, episode: float) -> float:
    """Real plant seconds consumed when ``episode`` (1-based) ended (``inf`` for ``inf``)."""
    if math.isinf(episode):
        return math.inf
    return float(log.episodes[int(episode) - 1]["plant_s"])


def aggregate(logs: Sequence[TrainingLog], field: str = "return", axis: str = "episode", grid: np.ndarray | None = None,
              window: int = 1, table: str = "episodes") -> dict[str, np.ndarray]:
    """Mean, min and max over seeds of one logged quantity on a common axis.

    Parameters
    ----------
    logs : sequence of TrainingLog
        One per seed.
    field : str
        Column of the episode (or evaluation) rows, e.g. ``"return"``, ``"upright_std_rad"``,
        ``"max_upright_std_rad"``.
    axis : {"episode", "plant_s"}
        Common x axis: training episodes, or real plant seconds (values interpolated onto ``grid``).
    grid : array, optional
        x values (default: the episodes/plant seconds of the shortest run).
    window : int
        Trailing moving average applied per seed before aggregating.
    table : {"episodes", "evaluations"}
        Which rows to read.

    Returns
    -------
    dict with ``x``, ``mean``, ``min``, ``max`` and ``per_seed`` (n_seeds, len(x)).
    """
    if len(logs) == 0:
        raise ValueError("logs must not be empty")
    if axis not in ("episode", "plant_s"):
        raise ValueError(f"axis must be 'episode' or 'plant_s', got {axis!r}")
    xs, ys = [], []
    for log in logs:
        x = log.column(axis, table)
        y = moving_average(log.column(field, table), window) if window > 1 else log.column(field, table)
        xs.append(x)
        ys.append(y)
    if grid is None:
        shortest = min(xs, key=lambda v: v[-1] if len(v) else -np.inf)
        grid = shortest
    grid = np.asarray(grid, dtype=float)
    per_seed = np.array([np.interp(grid, x, np.where(np.isfinite(y), y, np.nan), left=np.nan, right=np.nan) for x, y in zip(xs, ys)])
    return {"x": grid, "mean": np.nanmean(per_seed, axis=0), "min": np.nanmin(per_seed, axis=0),
            "max": np.nanmax(per_seed, axis=0), "per_seed": per_seed}

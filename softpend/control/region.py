"""Measured region of attraction of a stabilising controller about upright."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np
from tqdm.auto import tqdm

from softpend.checks import positive
from softpend.evaluation import Controller, evaluate_controller
from softpend.task import Task


@dataclass(frozen=True)
class RegionOfAttraction:
    """Largest tilt recovered from (every smaller one on the scan too) and the first that failed (``inf`` if none)."""

    largest_recovered_rad: float
    smallest_failed_rad: float


def recovers_from(
    controller: Controller, tilt_rad: float, task: Optional[Task] = None, duration_s: float = 4.0
) -> bool:
    """Whether ``controller`` brings the straight rod released at rest at ``tilt_rad`` back within
    0.02 rad of upright for the last second of ``duration_s``."""
    task = (task if task is not None else Task()).replace(start="upright")
    start = task.tilt_state(float(tilt_rad))
    (result,) = evaluate_controller(controller, task, seeds=(0,), duration_s=duration_s, initial_state=start).results
    if result.diverged is not None:
        return False
    last = result.theta_rad[-int(round(1.0 / task.dt_s)) :]
    return bool(np.all(np.abs(last) < 0.02))


def region_of_attraction_rad(
    controller: Controller,
    task: Optional[Task] = None,
    step_rad: float = 0.05,
    resolution_rad: float = 0.005,
    duration_s: float = 4.0,
    progress: bool = False,
) -> RegionOfAttraction:
    """Largest positive tilt the controller recovers from: a scan up in ``step_rad`` to the first failure, then
    bisection to ``resolution_rad``."""
    positive("step_rad", step_rad)
    positive("resolution_rad", resolution_rad)
    trial = lambda angle: recovers_from(controller, angle, task, duration_s=duration_s)  # noqa: E731
    low, high = 0.0, math.inf
    grid = np.arange(step_rad, math.pi / 2 + 1e-12, step_rad)
    for angle in tqdm(grid, desc="region of attraction", disable=not progress, leave=False):
        if trial(float(angle)):
            low = float(angle)
        else:
            high = float(angle)
            break
    while math.isfinite(high) and high - low > resolution_rad:
        middle = 0.5 * (low + high)
        low, high = (middle, high) if trial(middle) else (low, middle)
    return RegionOfAttraction(low, high)

"""Measured region of attraction of a stabilising controller about upright."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from softpend.checks import positive
from softpend.evaluation import Controller, evaluate_controller
from softpend.task import Task


@dataclass(frozen=True)
class RegionOfAttraction:
    """Largest tilt recovered from (every smaller one on the scan too) and the first that failed (``inf`` if none)."""

    largest_recovered_rad: float
    smallest_failed_rad: float


def region_of_attraction_rad(
    controller: Controller,
    task: Optional[Task] = None,
    step_rad: float = 0.05,
    resolution_rad: float = 0.005,
    duration_s: float = 4.0,
) -> RegionOfAttraction:
    """Largest positive tilt the controller recovers from (the straight rod released at rest there back within
    0.02 rad of upright for the last second of ``duration_s``): a scan up in ``step_rad`` to the first failure, then
    bisection to ``resolution_rad``."""
    positive("step_rad", step_rad)
    positive("resolution_rad", resolution_rad)
    task = (task if task is not None else Task()).replace(start="upright")

    def trial(tilt_rad: float) -> bool:
        run: dict[str, Any] = dict(seeds=(0,), duration_s=duration_s, initial_state=task.tilt_state(tilt_rad))
        (result,) = evaluate_controller(controller, task, **run).results
        last = result.theta_rad[-int(round(1.0 / task.dt_s)) :]
        return result.diverged is None and bool(np.all(np.abs(last) < 0.02))

    low, high = 0.0, math.inf
    for angle in map(float, np.arange(step_rad, math.pi / 2 + 1e-12, step_rad)):
        if not trial(angle):
            high = angle
            break
        low = angle
    while math.isfinite(high) and high - low > resolution_rad:
        middle = 0.5 * (low + high)
        low, high = (middle, high) if trial(middle) else (low, middle)
    return RegionOfAttraction(low, high)

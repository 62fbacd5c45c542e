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

__all__ = ["RegionOfAttraction", "recovers_from", "region_of_attraction_rad"]


@dataclass(frozen=True)
class RegionOfAttraction:
    """Result of :func:`region_of_attraction_rad`.

    Attributes
    ----------
    largest_recovered_rad : float
        Largest initial tilt of the straight rod (tip angle) from which the controller recovers, with every
        smaller tilt on the scan recovered as well [rad].
    smallest_failed_rad : float
        The first tilt that failed (``inf`` if none up to ``max_angle_rad``) [rad].
    tested_rad, recovered : arrays
        All tilts simulated and whether each recovered.
    """

    largest_recovered_rad: float
    smallest_failed_rad: float
    tested_rad: np.ndarray
    recovered: np.ndarray


def recovers_from(
    controller: Controller,
    tilt_rad: float,
    task: Optional[Task] = None,
    duration_s: float = 4.0,
    tolerance_rad: float = 0.02,
) -> bool:
    """Whether ``controller`` brings the rod of ``task`` released at rest, straight and tilted by ``tilt_rad``
    (hub and tip at that angle), back to ``|theta| < tolerance_rad`` for the whole last second of
    ``duration_s``."""
    task = (task if task is not None else Task()).replace(start="upright")
    summary = evaluate_controller(
        controller,
        task,
        seeds=(0,),
        duration_s=duration_s,
        initial_state=task.tilt_state(float(tilt_rad)),
    )
    result = summary.results[0]
    if result.diverged is not None:
        return False
    last = result.theta_rad[-int(round(1.0 / task.dt_s)) :]
    return bool(np.all(np.abs(last) < tolerance_rad))


def region_of_attraction_rad(
    controller: Controller,
    task: Optional[Task] = None,
    step_rad: float = 0.05,
    resolution_rad: float = 0.005,
    max_angle_rad: float = math.pi / 2,
    duration_s: float = 4.0,
    progress: bool = False,
) -> RegionOfAttraction:
    """Largest initial tip angle the controller recovers from (scan up in ``step_rad``, then bisect).

    Tilts are positive (the design is symmetric).  The scan stops at the first failure; bisection between
    the last success and that failure refines the boundary to ``resolution_rad``.

    Parameters
    ----------
    controller : Controller
    task : Task, optional
        Plant and rod (its ``torque_limit_nm`` is the saturation); default ``Task()``.
    step_rad, resolution_rad, max_angle_rad : float
        Coarse step, final resolution and upper end of the scan [rad].
    duration_s : float
        Length of each recovery trial [s].
    progress : bool
        Show a tqdm progress bar over the coarse scan.
    """
    for name, value in (("step_rad", step_rad), ("resolution_rad", resolution_rad), ("max_angle_rad", max_angle_rad)):
        positive(name, value)
    tested: list[float] = []
    outcome: list[bool] = []

    def trial(angle: float) -> bool:
        ok = recovers_from(controller, angle, task, duration_s=duration_s)
        tested.append(angle)
        outcome.append(ok)
        return ok

    low, high = 0.0, math.inf
    grid = np.arange(step_rad, max_angle_rad + 1e-12, step_rad)
    for angle in tqdm(grid, desc="region of attraction", disable=not progress, leave=False):
        if trial(float(angle)):
            low = float(angle)
        else:
            high = float(angle)
            break
    if math.isfinite(high):
        while high - low > resolution_rad:
            middle = 0.5 * (low + high)
            if trial(middle):
                low = middle
            else:
                high = middle
    return RegionOfAttraction(low, high, np.array(tested), np.array(outcome))

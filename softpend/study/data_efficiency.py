"""Plant seconds to balance: the grey-box route per seed, measured afterwards on the fresh report starts."""

from __future__ import annotations

import math
from typing import Any, Iterable, Optional

import numpy as np

from softpend.control.identified import RouteConfig, identify_until_robust, simulated_recorder
from softpend.evaluation import evaluate
from softpend.plant import RodParams
from softpend.study.fresh_starts import fresh_start_row
from softpend.study.greybox import perturbed_guess
from softpend.study.presets import REPORT_SEEDS
from softpend.task import Task

__all__ = ["greybox_route_rows", "greybox_route_figures"]


def greybox_route_rows(
    plant: str = "prb", seeds: Iterable[int] = range(10), config: Optional[RouteConfig] = None
) -> list[dict[str, Any]]:
    """One row per seed: the route on ``plant`` from the study's perturbed guess (plant seconds of excitation, how
    far it went), then its controller on the 20 fresh report starts; ``real_s_to_balance`` is infinite for a seed
    whose controller does not balance them."""
    config = config if config is not None else RouteConfig()
    task = Task(plant=plant)
    rows = []
    for seed in seeds:
        route = identify_until_robust(
            simulated_recorder(task, config, seed), perturbed_guess(RodParams()), config, seed
        )
        fresh = fresh_start_row(evaluate(route.controller, task, seeds=REPORT_SEEDS))
        rows.append(
            {
                "plant": plant,
                "seed": int(seed),
                "plant_s": route.plant_s,
                "robust": route.robust,
                "balanced_starts": fresh["balanced_starts"],
                "starts": fresh["starts"],
                "balances": fresh["run_balances"],
                "real_s_to_balance": route.plant_s if fresh["run_balances"] else math.inf,
                "max_relative_std": route.steps[-1]["max_relative_std"],
                "identified": route.identification.estimates,
            }
        )
    return rows


def greybox_route_figures(rows: list[dict[str, Any]], prefix: str, within_s: float) -> dict[str, float]:
    """Median and worst plant seconds to balance, seeds balanced, and seeds balanced within ``within_s``."""
    seconds = np.array([row["real_s_to_balance"] for row in rows], float)
    return {
        f"{prefix}_real_s_to_balance": float(np.median(seconds)),
        f"{prefix}_real_s_to_balance_worst": float(np.max(seconds)),
        f"{prefix}_seeds_balanced": float(np.sum(np.isfinite(seconds))),
        f"{prefix}_seeds_within_{within_s:g}s": float(np.sum(seconds <= within_s)),
    }

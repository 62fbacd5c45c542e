"""Trained controllers measured on fresh starts: the starts that no training or selection step saw.

An RL run picks its *selected* (best) agent on the evaluation seeds of its config and ends with its *final*
agent; PILCO decides that it has balanced on its own test seeds.  Every number this module reports is
measured afterwards, on :data:`softpend.study.presets.REPORT_SEEDS` (hanging starts of the task, 10 s each),
with the success rate's Wilson interval per run and, over the runs of a method, the interquartile mean with
a stratified bootstrap interval (:mod:`softpend.stats`).

A run *balances* when at least ``balanced_fraction`` (90 %) of its fresh starts swing up and keep the
upright standard deviation at most ``balance_std_rad`` (0.1 rad).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from softpend.evaluation import EvaluationSummary
from softpend.stats import aggregate_interval, wilson_interval
from softpend.study.presets import REPORT_SEEDS
from softpend.study.rl_runs import METHOD_NAMES, run_folder

__all__ = ["BALANCE_STD_RAD", "BALANCED_FRACTION", "aggregate_fresh_start_rows", "fresh_start_row",
           "pilco_fresh_start_rows", "rl_fresh_start_rows"]

#: Upright standard deviation of a start that counts as balanced [rad].
BALANCE_STD_RAD = 0.1
#: Share of fresh starts that must balance for a run to count as balanced.
BALANCED_FRACTION = 0.9
#: Names of the agents of an RL run, by :func:`softpend.rl.dqn.load_agent` ``which``.
AGENTS = {"best": "selected", "final": "final"}


def fresh_start_row(summary: EvaluationSummary, balance_std_rad: float = BALANCE_STD_RAD,
                    balanced_fraction: float = BALANCED_FRACTION) -> dict[str, Any]:
    """Success and balance figures of one controller over its fresh-start episodes."""
    n = len(summary.results)
    balanced = [math.isfinite(r.swing_up_time_s) and r.diverged is None and r.upright_std_rad <= balance_std_rad
                for r in summary.results]
    k = int(sum(balanced))
    low, high = wilson_interval(k, n)
    stds = [r.upright_std_rad for r, ok in zip(summary.results, balanced) if ok]
    return {
        "starts": n,
        "balanced_starts": k,
        "balanced_rate": k / n,
        "balanced_low": low,
        "balanced_high": high,
        "success_rate": summary.success_rate,
        "worst_balanced_std_rad": float(max(stds)) if stds else math.nan,
        "median_swing_up_time_s": summary.median("swing_up_time_s"),
        "run_balances": bool(k / n >= balanced_fraction),
    }


def rl_fresh_start_rows(runs_root: Path | str, seeds: Sequence[int], algos: Sequence[str] = ("dqn", "mbpo"),
                        report_seeds: Sequence[int] = REPORT_SEEDS, duration_s: float = 10.0,
                        which: Sequence[str] = ("best", "final")) -> list[dict[str, Any]]:
    """One row per (method, seed, agent) of the RL runs under ``runs_root``, measured on ``report_seeds``.

    Raises
    ------
    ValueError
        If a report seed is also one of a run's selection seeds (``config.eval_seeds``).
    """
    from softpend.rl.dqn import evaluate_agent, load_agent

    rows = []
    for algo in algos:
        for seed in seeds:
            for agent_kind in which:
                model, config = load_agent(run_folder(runs_root, algo, int(seed)), agent_kind)
                overlap = set(report_seeds) & set(config.eval_seeds)
                if overlap:
                    raise ValueError(f"report seeds {sorted(overlap)} were used to select the agents of {algo} seed {seed}")
                summary = evaluate_agent(model, config, seeds=tuple(report_seeds), duration_s=duration_s)
                rows.append({"method": METHOD_NAMES[algo], "seed": int(seed), "agent": AGENTS[agent_kind],
                             **fresh_start_row(summary)})
    return rows


def pilco_fresh_start_rows(results: Sequence[Any], report_seeds: Sequence[int] = REPORT_SEEDS,
                           duration_s: float = 10.0) -> list[dict[str, Any]]:
    """One row per PILCO run (its final policy, on the run's task), measured on ``report_seeds``."""
    from softpend.evaluation import evaluate_controller

    rows = []
    for result in results:
        overlap = set(report_seeds) & set(result.config.eval_seeds)
        if overlap:
            raise ValueError(f"report seeds {sorted(overlap)} were used by PILCO seed {result.config.seed}")
        summary = evaluate_controller(result.controller(), result.config.task, seeds=tuple(report_seeds),
                                      duration_s=duration_s)
        rows.append({"method": "PILCO", "seed": int(result.config.seed), "agent": "final", **fresh_start_row(summary)})
    return rows


def aggregate_fresh_start_rows(rows: Sequence[dict[str, Any]], seed: int = 0) -> list[dict[str, Any]]:
    """Per (method, agent): runs that balance, and the IQM of the balanced-start rate over runs with its 95 %
    stratified bootstrap interval (a single run gets its own rate and no interval)."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["method"], row["agent"]), []).append(row)
    out = []
    for (method, agent), group in groups.items():
        rates = np.array([g["balanced_rate"] for g in group])
        if len(rates) >= 2:
            interval = aggregate_interval(rates, "iqm", seed=seed)
            value, low, high = interval.value, interval.low, interval.high
        else:
            value, low, high = float(rates[0]), math.nan, math.nan
        out.append({"method": method, "agent": agent, "runs": len(group),
                    "runs_balanced": int(sum(g["run_balances"] for g in group)),
                    "iqm_balanced_rate": value, "iqm_low": low, "iqm_high": high})
    return out

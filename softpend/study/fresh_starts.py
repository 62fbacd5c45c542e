"""Trained controllers measured on fresh starts: the starts that no training or selection step saw.

An RL run picks its *selected* (best) agent on the evaluation seeds of its config and ends with its *final*
agent; PILCO decides that it has balanced on its own test seeds.  Every number this module reports is
measured afterwards, on :data:`softpend.study.presets.REPORT_SEEDS` (hanging starts of the task, 10 s each),
with the success rate's Wilson interval per run and, over the runs of a method, the interquartile mean with
a stratified bootstrap interval (:mod:`softpend.stats`).

A run *balances* when at least ``balanced_fraction`` (90 %) of its fresh starts swing up and keep the
upright standard deviation at most ``hold_std_rad`` (:data:`softpend.evaluation.HOLD_STD_RAD`).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from softpend.evaluation import HOLD_STD_RAD, TEST_EPISODE_S, EvaluationSummary, evaluate
from softpend.io.outputs import atomic_write
from softpend.io.reading import read_json_object
from softpend.stats import aggregate_interval, wilson_interval
from softpend.study.presets import REPORT_SEEDS
from softpend.study.rl_runs import METHOD_NAMES, run_folder

__all__ = [
    "BALANCED_FRACTION",
    "FRESH_STARTS_FILE",
    "aggregate_fresh_start_rows",
    "converged_fresh_start_rows",
    "fresh_start_row",
    "headline_figures",
    "pilco_fresh_start_rows",
    "rl_fresh_start_rows",
    "seed_rows",
]

#: Share of fresh starts that must balance for a run to count as balanced.
BALANCED_FRACTION = 0.9
#: Names of the agents of an RL run, by :func:`softpend.rl.dqn.load_agent` ``which``.
AGENTS = {"best": "selected", "final": "final"}


def fresh_start_row(
    summary: EvaluationSummary, hold_std_rad: float = HOLD_STD_RAD, balanced_fraction: float = BALANCED_FRACTION
) -> dict[str, Any]:
    """Success and balance figures of one controller over its fresh-start episodes (a start is *balanced* when it
    swings up and holds the upright std at most ``hold_std_rad``)."""
    n = len(summary.results)
    balanced = [
        math.isfinite(r.swing_up_time_s) and r.diverged is None and r.upright_std_rad <= hold_std_rad
        for r in summary.results
    ]
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


#: File in an RL run folder that keeps its fresh-start rows (see :func:`rl_fresh_start_rows`).
FRESH_STARTS_FILE = "fresh_starts.json"


@functools.lru_cache(maxsize=1)
def _scoring_source() -> bytes:
    """The source of the code that scores an episode (read once per process)."""
    import inspect

    import softpend.evaluation as evaluation

    return (inspect.getsource(evaluation) + inspect.getsource(fresh_start_row)).encode()


def _evaluation_key(agent_path: Path, report_seeds: Sequence[int], duration_s: float) -> str:
    """What a fresh-start row depends on: the agent's bytes, the starts, the duration and the code that scores."""
    digest = hashlib.sha256(agent_path.read_bytes())
    digest.update(_scoring_source())
    digest.update(json.dumps([list(map(int, report_seeds)), float(duration_s)]).encode())
    return digest.hexdigest()


def _refuse_selection_starts(report_seeds: Sequence[int], selection_seeds: Sequence[int], what: str) -> None:
    """``ValueError`` if a report start is one of the starts that selected ``what``."""
    overlap = set(report_seeds) & set(selection_seeds)
    if overlap:
        raise ValueError(f"report seeds {sorted(overlap)} were used to select {what}")


def rl_fresh_start_rows(
    runs_root: Path | str,
    seeds: Sequence[int],
    algos: Sequence[str] = ("dqn", "mbpo"),
    report_seeds: Sequence[int] = REPORT_SEEDS,
    duration_s: float = TEST_EPISODE_S,
    which: Sequence[str] = ("best", "final"),
    configs: Optional[Mapping[str, Any]] = None,
) -> list[dict[str, Any]]:
    """One row per (method, seed, agent) of the RL runs under ``runs_root``, measured on ``report_seeds``
    (``configs``: ``{algo: config}`` of the runs, which picks their folders where runs of several settings
    share ``runs_root``; :func:`softpend.study.rl_runs.run_folder`).

    Each run folder keeps its rows in :data:`FRESH_STARTS_FILE`, keyed by the agent file's bytes, the starts, the
    duration and the source of the evaluation code, so that the figures that report them evaluate each agent
    once; any change of those evaluates again.

    Raises
    ------
    ValueError
        If a report seed is also one of a run's selection seeds (``config.selection_seeds``).
    """
    from softpend.rl.dqn import evaluate_agent, load_agent

    rows = []
    for algo in algos:
        for seed in seeds:
            folder = run_folder(runs_root, algo, int(seed), (configs or {}).get(algo))
            cache_path = folder / FRESH_STARTS_FILE
            cache = read_json_object(cache_path, 10**6) or {}
            changed = False
            for agent_kind in which:
                model, config = load_agent(folder, agent_kind)
                _refuse_selection_starts(report_seeds, config.selection_seeds, f"the agents of {algo} seed {seed}")
                agent_file = folder / ("best_agent.zip" if agent_kind == "best" else "agent.zip")
                if not agent_file.exists():
                    agent_file = folder / "agent.zip"
                key = _evaluation_key(agent_file, report_seeds, duration_s)
                cached = cache.get(agent_kind)
                if isinstance(cached, dict) and cached.get("key") == key and isinstance(cached.get("row"), dict):
                    figures = cached["row"]
                else:
                    summary = evaluate_agent(model, config, seeds=tuple(report_seeds), duration_s=duration_s)
                    figures = fresh_start_row(summary)
                    cache[agent_kind] = {"key": key, "row": figures}
                    changed = True
                rows.append({"method": METHOD_NAMES[algo], "seed": int(seed), "agent": AGENTS[agent_kind], **figures})
            if changed:
                with atomic_write(cache_path, "w") as handle:
                    handle.write(json.dumps(cache, indent=1))  # Infinity and NaN kept (read back by Python only)
    return rows


def pilco_fresh_start_rows(
    results: Sequence[Any], report_seeds: Sequence[int] = REPORT_SEEDS, duration_s: float = TEST_EPISODE_S
) -> list[dict[str, Any]]:
    """One row per PILCO run (its final policy, on the run's task), measured on ``report_seeds``."""
    rows = []
    for result in results:
        _refuse_selection_starts(
            report_seeds, result.config.eval_seeds, f"the policy of PILCO seed {result.config.seed}"
        )
        summary = evaluate(result.controller(), result.config.task, seeds=tuple(report_seeds), duration_s=duration_s)
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
        out.append(
            {
                "method": method,
                "agent": agent,
                "runs": len(group),
                "runs_balanced": int(sum(g["run_balances"] for g in group)),
                "iqm_balanced_rate": value,
                "iqm_low": low,
                "iqm_high": high,
            }
        )
    return out


def seed_rows(
    logs_by_algo: Mapping[str, Sequence[Any]], fresh_rows: Sequence[dict[str, Any]], pilco_results: Sequence[Any] = ()
) -> list[dict[str, Any]]:
    """One row per (method, seed) of what a run cost and whether its *final* agent balances fresh starts.

    ``plant_s_to_balance`` is the training plant time the run consumed [s] when its final agent (policy) balances
    the fresh starts (:func:`fresh_start_row` ``run_balances``), ``inf`` when it does not: a run that balanced
    during training and lost it, or never balanced, did not reach the goal within its budget.  For PILCO the
    time is that of its first policy that balanced its own test starts (``real_seconds_to_balance``), counted
    only when the final policy balances the fresh starts too.

    Parameters
    ----------
    logs_by_algo : mapping
        ``{"dqn": [TrainingLog, ...], "mbpo": [...]}``.
    fresh_rows : sequence of dict
        :func:`rl_fresh_start_rows` (and :func:`pilco_fresh_start_rows`) rows; the ``final`` ones are used.
    pilco_results : sequence of PilcoResult
        PILCO runs (optional).
    """
    final = {(r["method"], int(r["seed"])): r for r in fresh_rows if r["agent"] == "final"}
    rows = []
    for algo, logs in logs_by_algo.items():
        method = METHOD_NAMES[algo]
        for log in logs:
            fresh = final.get((method, int(log.seed)))
            if fresh is None:
                raise ValueError(f"no fresh-start row of the final agent of {method} seed {log.seed}")
            rows.append(
                {
                    "method": method,
                    "seed": int(log.seed),
                    "episodes": log.n_episodes,
                    "plant_s": log.plant_s,
                    "stopped_balanced": log.stop_reason is not None,
                    "final_balanced_starts": fresh["balanced_starts"],
                    "starts": fresh["starts"],
                    "final_balances": fresh["run_balances"],
                    "plant_s_to_balance": log.plant_s if fresh["run_balances"] else math.inf,
                }
            )
    for result in pilco_results:
        seed = int(result.config.seed)
        fresh = final.get(("PILCO", seed))
        if fresh is None:
            raise ValueError(f"no fresh-start row of PILCO seed {seed}")
        seconds = float(result.real_seconds_to_balance)
        rows.append(
            {
                "method": "PILCO",
                "seed": seed,
                "episodes": len(result.records),
                "plant_s": float(result.plant_seconds_total),
                "stopped_balanced": math.isfinite(seconds),
                "final_balanced_starts": fresh["balanced_starts"],
                "starts": fresh["starts"],
                "final_balances": fresh["run_balances"],
                "plant_s_to_balance": seconds if fresh["run_balances"] else math.inf,
            }
        )
    return rows


def headline_figures(
    rows: Sequence[dict[str, Any]], within_s: float = 30.0, ratio: float = 3.0, seed: int = 0
) -> dict[str, float]:
    """The ten-seed figures of the learning methods from :func:`seed_rows` rows.

    ``seeds_balanced_<m>`` (runs whose final agent balances the fresh starts) and ``seeds_<m>`` (runs) for
    ``m`` in ``dqn``, ``mbpo``, ``pilco``; ``<m>_real_s_to_balance`` (median over seeds of
    ``plant_s_to_balance``, ``inf`` counting as never) with its 95 % bootstrap interval (``_low``, ``_high``);
    ``mbpo_over_dqn_real_s_ratio`` (of those medians); ``mbpo_seeds_3x_fewer_than_dqn`` (seeds whose DQN-MBPO
    run balanced with at most ``1 / ratio`` of the DQN run's plant seconds of the same seed, a DQN run that never
    balanced counting as infinitely slow); ``pilco_seeds_within_30s`` (PILCO runs that balanced within
    ``within_s`` plant seconds).
    """
    keys = {METHOD_NAMES["dqn"]: "dqn", METHOD_NAMES["mbpo"]: "mbpo", "PILCO": "pilco"}
    by_method: dict[str, dict[int, dict[str, Any]]] = {}
    for row in rows:
        by_method.setdefault(keys[row["method"]], {})[int(row["seed"])] = row
    out: dict[str, float] = {}
    for key, group in by_method.items():
        seconds = np.array([r["plant_s_to_balance"] for r in group.values()], dtype=float)
        out[f"seeds_{key}"] = float(len(group))
        out[f"seeds_balanced_{key}"] = float(sum(bool(r["final_balances"]) for r in group.values()))
        out[f"{key}_real_s_to_balance"] = float(np.median(seconds))
        if len(seconds) >= 2:
            interval = aggregate_interval(seconds, "median", seed=seed)
            out[f"{key}_real_s_to_balance_low"], out[f"{key}_real_s_to_balance_high"] = interval.low, interval.high
    if "dqn" in by_method and "mbpo" in by_method:
        mf, mb = out["dqn_real_s_to_balance"], out["mbpo_real_s_to_balance"]
        out["mbpo_over_dqn_real_s_ratio"] = mf / mb if math.isfinite(mb) and mb > 0 else math.nan
        common = sorted(set(by_method["dqn"]) & set(by_method["mbpo"]))
        out["mbpo_seeds_3x_fewer_than_dqn"] = float(
            sum(
                math.isfinite(by_method["mbpo"][s]["plant_s_to_balance"])
                and ratio * by_method["mbpo"][s]["plant_s_to_balance"] <= by_method["dqn"][s]["plant_s_to_balance"]
                for s in common
            )
        )
    if "pilco" in by_method:
        out["pilco_seeds_within_30s"] = float(
            sum(r["plant_s_to_balance"] <= within_s for r in by_method["pilco"].values())
        )
    return out


def perturbed_rod_row(
    controller: Any,
    task: Any,
    spread: float = 0.15,
    report_seeds: Sequence[int] = REPORT_SEEDS,
    duration_s: float = TEST_EPISODE_S,
) -> dict[str, Any]:
    """One controller on rods that differ from its model: :func:`fresh_start_row` figures over ``report_seeds``,
    where the start seeded ``s`` runs on the rod :func:`softpend.plant.randomisation.randomised_rod` draws from
    ``numpy.random.default_rng(s)`` with ``spread`` (every field of
    :data:`~softpend.plant.randomisation.RANDOMISED_FIELDS` scaled by its own factor in ``[1 - spread,
    1 + spread]``), from that seed's hanging start.  The controller keeps its own model of the rod (for a
    trained agent: the task it was trained on)."""
    summary = evaluate(
        controller, task, name="perturbed rods", seeds=report_seeds, duration_s=duration_s, rod_spread=spread
    )
    return {"spread": float(spread), **fresh_start_row(summary)}


def converged_fresh_start_rows(
    runs_root: Path | str,
    seeds: Sequence[int],
    algos: Sequence[str] = ("dqn", "mbpo"),
    report_seeds: Sequence[int] = REPORT_SEEDS,
    duration_s: float = TEST_EPISODE_S,
    which: str = "final",
) -> list[dict[str, Any]]:
    """:func:`rl_fresh_start_rows` of one agent per run on a *converged* simulation of the same rod: the batched
    chain at its default sub-steps (:func:`softpend.rl.dqn.evaluate_agents_batched`, whose hub angle stays far
    closer to the Exudyn plant at 200 sub-steps than the task's Exudyn plant at 2 sub-steps does:
    :func:`softpend.study.simulators.hub_errors_rad`), from the same starts.  A controller that holds on the task's plant but not here relies on
    what the task's coarse time step does to the rod's bending modes, which a real rod would not do."""
    from softpend.rl.dqn import evaluate_agents_batched, load_agent

    runs = [(algo, int(seed)) for algo in algos for seed in seeds]
    agents = {}
    for algo, seed in runs:
        agents[algo, seed] = load_agent(run_folder(runs_root, algo, seed), which)
        _refuse_selection_starts(
            report_seeds, agents[algo, seed][1].selection_seeds, f"the agents of {algo} seed {seed}"
        )
    # the agents that share what the batched episodes depend on step together (one batch each)
    groups: dict[tuple[Any, ...], list[tuple[str, int]]] = {}
    for run, (_, config) in agents.items():
        groups.setdefault((config.task, config.action_repeat, config.n_torque_levels), []).append(run)
    summaries: dict[tuple[str, int], EvaluationSummary] = {}
    for members in groups.values():
        config = agents[members[0]][1]
        evaluated = evaluate_agents_batched(
            [agents[run][0] for run in members], config, seeds=tuple(report_seeds), duration_s=duration_s
        )
        summaries.update(zip(members, evaluated))
    return [
        {
            "method": METHOD_NAMES[algo],
            "seed": seed,
            "agent": AGENTS[which],
            "plant": "converged",
            **fresh_start_row(summaries[algo, seed]),
        }
        for algo, seed in runs
    ]

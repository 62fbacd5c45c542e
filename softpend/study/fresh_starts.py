"""Trained controllers measured on fresh starts (:data:`~softpend.study.presets.REPORT_SEEDS`): per-run rows, their
aggregates over runs and the headline figures."""

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

#: Share of fresh starts that must balance for a run to count as balanced.
BALANCED_FRACTION = 0.9
#: Names of the agents of an RL run, by :func:`softpend.rl.dqn.load_agent` ``which``.
AGENTS = {"best": "selected", "final": "final"}
#: File in an RL run folder that keeps its fresh-start rows.
FRESH_STARTS_FILE = "fresh_starts.json"


def held_starts(summary: EvaluationSummary, hold_std_rad: float) -> list[bool]:
    """Per start: swung up, did not diverge and kept the upright std at most ``hold_std_rad``."""
    return [
        math.isfinite(r.swing_up_time_s) and r.diverged is None and r.upright_std_rad <= hold_std_rad
        for r in summary.results
    ]


def fresh_start_row(summary: EvaluationSummary) -> dict[str, Any]:
    """Success and balance figures of one controller over its fresh-start episodes (held within
    :data:`~softpend.evaluation.HOLD_STD_RAD`; the run balances when :data:`BALANCED_FRACTION` of them are held)."""
    n, balanced = len(summary.results), held_starts(summary, HOLD_STD_RAD)
    k = int(sum(balanced))
    low, high = wilson_interval(k, n)
    stds = [r.upright_std_rad for r, ok in zip(summary.results, balanced) if ok]
    row = {"starts": n, "balanced_starts": k, "balanced_rate": k / n, "balanced_low": low, "balanced_high": high}
    row |= {"success_rate": summary.success_rate, "worst_balanced_std_rad": float(max(stds)) if stds else math.nan}
    row["median_swing_up_time_s"] = summary.median("swing_up_time_s")
    return row | {"run_balances": bool(k / n >= BALANCED_FRACTION)}


@functools.lru_cache(maxsize=1)
def _scoring_source() -> bytes:
    import inspect

    import softpend.evaluation as evaluation

    return "".join(inspect.getsource(code) for code in (evaluation, held_starts, fresh_start_row)).encode()


def _refuse_selection_starts(report_seeds: Sequence[int], selection_seeds: Sequence[int], what: str) -> None:
    if overlap := set(report_seeds) & set(selection_seeds):
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
    """One row per (method, seed, agent) of the RL runs on ``report_seeds`` (``configs``: ``{algo: config}`` picks the
    folders), cached in :data:`FRESH_STARTS_FILE` under a hash of the agent, the scoring code, the starts and the
    duration; ``ValueError`` if a report seed selected a run's agents."""
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
                best = folder / "best_agent.zip"
                agent_file = best if agent_kind == "best" and best.exists() else folder / "agent.zip"
                starts = json.dumps([list(map(int, report_seeds)), float(duration_s)]).encode()
                key = hashlib.sha256(agent_file.read_bytes() + _scoring_source() + starts).hexdigest()
                cached = cache.get(agent_kind)
                if not (isinstance(cached, dict) and cached.get("key") == key and isinstance(cached.get("row"), dict)):
                    summary = evaluate_agent(model, config, seeds=tuple(report_seeds), duration_s=duration_s)
                    cached = cache[agent_kind] = {"key": key, "row": fresh_start_row(summary)}
                    changed = True
                row = {"method": METHOD_NAMES[algo], "seed": int(seed), "agent": AGENTS[agent_kind]}
                rows.append(row | cached["row"])
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
        seed = int(result.config.seed)
        _refuse_selection_starts(report_seeds, result.config.eval_seeds, f"the policy of PILCO seed {seed}")
        summary = evaluate(result.controller(), result.config.task, seeds=tuple(report_seeds), duration_s=duration_s)
        rows.append({"method": "PILCO", "seed": seed, "agent": "final", **fresh_start_row(summary)})
    return rows


def aggregate_fresh_start_rows(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (method, agent): runs that balance, and the IQM of the balanced-start rate over runs with its 95 %
    stratified bootstrap interval (a single run gets its own rate and no interval)."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["method"], row["agent"]), []).append(row)
    out = []
    for (method, agent), group in groups.items():
        rates = np.array([g["balanced_rate"] for g in group])
        iqm = aggregate_interval(rates, "iqm", seed=0) if len(rates) >= 2 else None
        figures = (iqm.value, iqm.low, iqm.high) if iqm else (float(rates[0]), math.nan, math.nan)
        balanced = sum(g["run_balances"] for g in group)
        row = {"method": method, "agent": agent, "runs": len(group), "runs_balanced": balanced}
        out.append(row | dict(zip(("iqm_balanced_rate", "iqm_low", "iqm_high"), figures)))
    return out


def seed_rows(
    logs_by_algo: Mapping[str, Sequence[Any]], fresh_rows: Sequence[dict[str, Any]], pilco_results: Sequence[Any] = ()
) -> list[dict[str, Any]]:
    """One row per (method, seed): what the run cost and whether its final agent balances the fresh starts
    (``plant_s_to_balance``, else ``inf``); ``logs_by_algo``: ``{algo: [TrainingLog]}``."""
    final = {(r["method"], int(r["seed"])): r for r in fresh_rows if r["agent"] == "final"}
    runs = [
        (METHOD_NAMES[algo], int(log.seed), log.n_episodes, log.plant_s, log.stop_reason is not None, log.plant_s)
        for algo, logs in logs_by_algo.items()
        for log in logs
    ]
    for result in pilco_results:
        seconds, plant_s = float(result.real_seconds_to_balance), float(result.plant_seconds_total)
        runs.append(("PILCO", int(result.config.seed), len(result.records), plant_s, math.isfinite(seconds), seconds))
    rows = []
    for method, seed, episodes, plant_s, stopped, to_balance in runs:
        if (fresh := final.get((method, seed))) is None:
            what = f"the final agent of {method} seed {seed}" if method != "PILCO" else f"PILCO seed {seed}"
            raise ValueError(f"no fresh-start row of {what}")
        row = {"method": method, "seed": seed, "episodes": episodes, "plant_s": plant_s, "stopped_balanced": stopped}
        row |= {"final_balanced_starts": fresh["balanced_starts"], "starts": fresh["starts"]}
        balances = fresh["run_balances"]
        rows.append(row | {"final_balances": balances, "plant_s_to_balance": to_balance if balances else math.inf})
    return rows


def headline_figures(rows: Sequence[dict[str, Any]]) -> dict[str, float]:
    """Per method ``m`` of :func:`seed_rows` rows: ``seeds_<m>``, ``seeds_balanced_<m>``, ``<m>_real_s_to_balance``
    (median, ``_low``/``_high``); ``mbpo_over_dqn_real_s_ratio``, ``mbpo_seeds_3x_fewer_than_dqn``, ``pilco_seeds_within_30s``."""
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
            interval = aggregate_interval(seconds, "median", seed=0)
            out[f"{key}_real_s_to_balance_low"], out[f"{key}_real_s_to_balance_high"] = interval.low, interval.high
    seconds_of = {key: {seed: r["plant_s_to_balance"] for seed, r in group.items()} for key, group in by_method.items()}
    if "dqn" in seconds_of and "mbpo" in seconds_of:
        (mf, mf_s), (mb, mb_s) = ((out[f"{k}_real_s_to_balance"], seconds_of[k]) for k in ("dqn", "mbpo"))
        out["mbpo_over_dqn_real_s_ratio"] = mf / mb if math.isfinite(mb) and mb > 0 else math.nan
        fewer = [math.isfinite(mb_s[seed]) and 3.0 * mb_s[seed] <= mf_s[seed] for seed in set(mf_s) & set(mb_s)]
        out["mbpo_seeds_3x_fewer_than_dqn"] = float(sum(fewer))
    if "pilco" in seconds_of:
        out["pilco_seeds_within_30s"] = float(sum(value <= 30.0 for value in seconds_of["pilco"].values()))
    return out


def perturbed_rod_row(
    controller: Any,
    task: Any,
    spread: float = 0.15,
    report_seeds: Sequence[int] = REPORT_SEEDS,
    duration_s: float = TEST_EPISODE_S,
) -> dict[str, Any]:
    """:func:`fresh_start_row` of a controller over ``report_seeds``, each on a rod randomised by ``spread``."""
    summary = evaluate(
        controller, task, name="perturbed rods", seeds=report_seeds, duration_s=duration_s, rod_spread=spread
    )
    return {"spread": float(spread), **fresh_start_row(summary)}


def converged_fresh_start_rows(
    runs_root: Path | str, seeds: Sequence[int], report_seeds: Sequence[int] = REPORT_SEEDS
) -> list[dict[str, Any]]:
    """:func:`rl_fresh_start_rows` of each run's final agent on the batched chain at its default (converged) sub-steps."""
    from softpend.rl.dqn import evaluate_agents_batched, load_agent

    runs = [(algo, int(seed)) for algo in METHOD_NAMES for seed in seeds]
    agents = {run: load_agent(run_folder(runs_root, *run), "final") for run in runs}
    groups: dict[tuple[Any, ...], list[tuple[str, int]]] = {}
    for run, (_, config) in agents.items():
        _refuse_selection_starts(report_seeds, config.selection_seeds, f"the agents of {run[0]} seed {run[1]}")
        groups.setdefault((config.task, config.action_repeat, config.n_torque_levels), []).append(run)
    summaries: dict[tuple[str, int], EvaluationSummary] = {}
    for members in groups.values():
        config = agents[members[0]][1]
        evaluated = evaluate_agents_batched(
            [agents[run][0] for run in members], config, seeds=tuple(report_seeds), duration_s=TEST_EPISODE_S
        )
        summaries.update(zip(members, evaluated))
    final = {"agent": AGENTS["final"], "plant": "converged"}
    return [{"method": METHOD_NAMES[a], "seed": s, **final, **fresh_start_row(summaries[a, s])} for a, s in runs]

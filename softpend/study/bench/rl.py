"""``softpend bench --only rl``: DQN training speed, and the ten-seed figures of DQN and DQN-MBPO on fresh starts.

* ``dqn_train_steps_per_s`` -- agent steps per wall-clock second of model-free DQN training (environment
  with action repeat, replay, gradient steps; 10 episodes after a short warm-up).
* The runs of the book's full profile (:data:`softpend.study.presets.RL_BOOK`: every seed, the episode budgets,
  folder ``runs/rl-book``; reused when present, trained otherwise), their final agents measured on the fresh
  starts :data:`softpend.study.presets.REPORT_SEEDS` (:func:`softpend.study.fresh_starts.rl_fresh_start_rows`),
  condensed by :func:`softpend.study.fresh_starts.headline_figures`: ``seeds_balanced_dqn`` and
  ``seeds_balanced_mbpo`` (runs whose final agent balances >= 90 % of the fresh starts with upright std
  <= 0.1 rad), ``dqn_real_s_to_balance`` and ``mbpo_real_s_to_balance`` (median over seeds of the training
  plant seconds of a run whose final agent balances; ``inf`` for one that does not) with bootstrap intervals,
  ``mbpo_over_dqn_real_s_ratio`` and ``mbpo_seeds_3x_fewer_than_dqn``; ``seeds_balanced_<m>_converged_plant``:
  the same final agents from the same starts on a converged simulation of the rod
  (:func:`softpend.study.fresh_starts.converged_fresh_start_rows`, the batched chain).
* ``full_profile_train_cpu_s`` -- CPU seconds of training all those runs (the training logs' ``cpu_s``,
  ``nan`` if a run predates that column); ``full_profile_train_2core_s`` is half of it: the wall time on two
  otherwise idle cores running two single-threaded runs at a time, if the runs pack perfectly (a lower bound).
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from typing import Any, Sequence

from softpend.study.presets import DQN


def dqn_train_steps_per_s(episodes: int = 10) -> float:
    """Agent steps per second of DQN training, learning already started: timed between the ends of the first
    and the last episode of a ``1 + episodes`` run (the training log's ``wall_s``), so that start-up,
    evaluation and checkpoint writing are excluded."""
    from softpend.rl.dqn import train_dqn

    config = dataclasses.replace(
        DQN,
        learning_starts=0,
        eval_every_episodes=10_000,
        checkpoint_every_episodes=10_000,
        eval_seeds=(0,),
        eval_duration_s=0.1,
    )
    with tempfile.TemporaryDirectory() as tmp:
        _, log = train_dqn(config, seed=0, episodes=1 + episodes, run_dir=tmp, progress=False)
    elapsed = log.episodes[-1]["wall_s"] - log.episodes[0]["wall_s"]
    return episodes * config.episode_agent_steps / elapsed


def training_cpu_s(log) -> float:
    """CPU seconds a run spent training, final evaluation included (``nan`` for a run without ``cpu_s``)."""
    values = [row.get("cpu_s", math.nan) for row in log.episodes + log.evaluations]
    return float(max(values)) if values and all(math.isfinite(v) for v in values) else math.nan


def bench_rl() -> dict[str, float]:
    """The "rl" benchmark group (see the module docstring)."""
    from softpend.study.fresh_starts import converged_fresh_start_rows, headline_figures, rl_fresh_start_rows, seed_rows
    from softpend.study.presets import RL_BOOK
    from softpend.study.rl_runs import METHOD_NAMES, figure_runs

    steps_per_s = dqn_train_steps_per_s()
    runs = figure_runs(RL_BOOK.episodes_dqn, RL_BOOK.episodes_mbpo, RL_BOOK.seeds, RL_BOOK.runs_root, progress=True)
    logs: dict[str, Sequence[Any]] = {"dqn": runs[METHOD_NAMES["dqn"]], "mbpo": runs[METHOD_NAMES["mbpo"]]}
    fresh = rl_fresh_start_rows(RL_BOOK.runs_root, RL_BOOK.seeds, which=("final",))
    converged = converged_fresh_start_rows(RL_BOOK.runs_root, RL_BOOK.seeds)
    cpu_s = sum(training_cpu_s(log) for group in logs.values() for log in group)
    return {
        "dqn_train_steps_per_s": steps_per_s,
        **headline_figures(seed_rows(logs, fresh)),
        **{
            f"seeds_balanced_{algo}_converged_plant": float(
                sum(r["run_balances"] for r in converged if r["method"] == METHOD_NAMES[algo])
            )
            for algo in ("dqn", "mbpo")
        },
        "full_profile_train_cpu_s": cpu_s,
        "full_profile_train_2core_s": cpu_s / 2.0,
    }

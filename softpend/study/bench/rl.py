"""``softpend bench --only rl``: DQN training speed and the book's DQN and DQN-MBPO ten-seed figures and CPU time."""

from __future__ import annotations

import dataclasses
import math
import tempfile
from typing import Any, Sequence

from softpend.study.presets import DQN


def dqn_train_steps_per_s(episodes: int = 10) -> float:
    """Agent steps per second of DQN training between the ends of the first and the last of ``1 + episodes``."""
    from softpend.rl.dqn import train_dqn

    rare = dict(eval_every_episodes=10_000, checkpoint_every_episodes=10_000)
    config = dataclasses.replace(DQN, learning_starts=0, **rare, eval_seeds=(0,), eval_duration_s=0.1)
    with tempfile.TemporaryDirectory() as tmp:
        _, log = train_dqn(config, seed=0, episodes=1 + episodes, run_dir=tmp, progress=False)
    elapsed = log.episodes[-1]["wall_s"] - log.episodes[0]["wall_s"]
    return episodes * config.episode_agent_steps / elapsed


def training_cpu_s(log) -> float:
    """CPU seconds a run spent training, final evaluation included (``nan`` for a run without ``cpu_s``)."""
    values = [row.get("cpu_s", math.nan) for row in log.episodes + log.evaluations]
    return float(max(values)) if values and all(math.isfinite(v) for v in values) else math.nan


def bench_rl() -> dict[str, float]:
    """The ``rl`` benchmark group (see the module docstring)."""
    from softpend.study.fresh_starts import converged_fresh_start_rows, headline_figures, rl_fresh_start_rows, seed_rows
    from softpend.study.presets import RL_BOOK
    from softpend.study.rl_runs import METHOD_NAMES, figure_runs

    steps_per_s = dqn_train_steps_per_s()
    runs = figure_runs(RL_BOOK.episodes_dqn, RL_BOOK.episodes_mbpo, RL_BOOK.seeds, RL_BOOK.runs_root, progress=True)
    logs: dict[str, Sequence[Any]] = {"dqn": runs[METHOD_NAMES["dqn"]], "mbpo": runs[METHOD_NAMES["mbpo"]]}
    fresh = rl_fresh_start_rows(RL_BOOK.runs_root, RL_BOOK.seeds, which=("final",))
    converged = converged_fresh_start_rows(RL_BOOK.runs_root, RL_BOOK.seeds)
    cpu_s = sum(training_cpu_s(log) for group in logs.values() for log in group)
    balanced = {algo: sum(r["run_balances"] for r in converged if r["method"] == METHOD_NAMES[algo]) for algo in logs}
    return {
        "dqn_train_steps_per_s": steps_per_s,
        **headline_figures(seed_rows(logs, fresh)),
        **{f"seeds_balanced_{algo}_converged_plant": float(count) for algo, count in balanced.items()},
        "full_profile_train_cpu_s": cpu_s,
        "full_profile_train_2core_s": cpu_s / 2.0,
    }

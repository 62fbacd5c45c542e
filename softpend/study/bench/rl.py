"""``softpend bench --only rl``: DQN training speed and plant seconds until the agents balance.

* ``dqn_train_steps_per_s`` -- agent steps per wall-clock second of model-free DQN training (environment
  with action repeat, replay, gradient steps; 10 episodes after a short warm-up).
* ``dqn_real_s_to_balance`` / ``mbpo_real_s_to_balance`` -- median over seeds (0, 1, 2) of the real plant
  seconds of training until the periodic evaluation balances (every evaluation seed swings up and holds
  ``upright_std_rad <= 0.2``); ``inf`` when a run never does.  The runs are those of the book's full
  profile (:func:`softpend.study.rl_runs.figure_configs`, ``RL_EPISODES``, folder ``runs/rl-book``):
  reused when present, trained otherwise.
* ``mbpo_over_dqn_real_s_ratio`` -- DQN over MBPO plant seconds to balance (the target is >= 3).
* ``full_profile_train_cpu_s`` -- CPU seconds of training all six runs (the training logs' ``cpu_s``,
  ``nan`` if a run predates that column); ``full_profile_train_2core_s`` is half of it: the wall time of the
  full profile on two otherwise idle cores running two single-threaded runs at a time (as
  :func:`~softpend.study.rl_runs.figure_runs` does), if the runs pack perfectly (a lower bound; the target
  is <= 1200 s).
"""

from __future__ import annotations

import math
import tempfile

from softpend.study.presets import RL_EPISODES
from softpend.rl.config import DQNConfig

SEEDS = (0, 1, 2)
ROOT = "runs/rl-book"


def dqn_train_steps_per_s(episodes: int = 10) -> float:
    """Agent steps per second of DQN training, learning already started: timed between the ends of the first
    and the last episode of a ``1 + episodes`` run (the training log's ``wall_s``), so that start-up,
    evaluation and checkpoint writing are excluded."""
    from softpend.rl.dqn import train_dqn

    config = DQNConfig(learning_starts=0, eval_every_episodes=10_000, checkpoint_every_episodes=10_000, eval_seeds=(0,), eval_duration_s=0.1)
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
    from softpend.study.rl_runs import METHOD_NAMES, figure_runs, median_real_s_to_balance

    steps_per_s = dqn_train_steps_per_s()
    runs = figure_runs(RL_EPISODES["dqn"], RL_EPISODES["mbpo"], SEEDS, ROOT, progress=True)
    dqn_logs, mbpo_logs = runs[METHOD_NAMES["dqn"]], runs[METHOD_NAMES["mbpo"]]
    cpu_s = sum(training_cpu_s(log) for log in dqn_logs + mbpo_logs)
    dqn_s = median_real_s_to_balance(dqn_logs)
    mbpo_s = median_real_s_to_balance(mbpo_logs)
    return {
        "dqn_train_steps_per_s": steps_per_s,
        "dqn_real_s_to_balance": dqn_s,
        "mbpo_real_s_to_balance": mbpo_s,
        "mbpo_over_dqn_real_s_ratio": dqn_s / mbpo_s if math.isfinite(mbpo_s) and mbpo_s > 0 else math.nan,
        "full_profile_train_cpu_s": cpu_s,
        "full_profile_train_2core_s": cpu_s / 2.0,
    }

"""Reinforcement learning: model-free DQN and model-based DQN-MBPO that swing the soft rod up and balance it.

* :mod:`softpend.rl.config` -- the settings (``DQNConfig``, ``MBPOConfig``; the book's are ``book/hparams/*.yml``);
* :mod:`softpend.rl.training_env` -- the training environment (action repeat, episode length) and the
  controller that runs an agent through the shared evaluation;
* :mod:`softpend.rl.dqn` -- the training loop (progress bar, periodic evaluation, resumable checkpoints);
* :mod:`softpend.rl.mbpo` -- DQN-MBPO (model rollouts branched from real states, ensemble refits);
* :mod:`softpend.rl.training_log` -- per-episode and per-evaluation records in plant time;
* :mod:`softpend.rl.curves` -- learning curves in plant time and the "asymptotic reward" definition;
* :mod:`softpend.study.rl_runs` -- multi-seed runs shared by Figures 4-6 and the benchmarks;
* :mod:`softpend.study.figures.rl` -- the plotting helpers of Figures 4-6;
* :mod:`softpend.study.bench.rl` -- ``softpend bench --only rl``;
* :mod:`softpend.commands.train_rl` -- ``softpend train --algo dqn|mbpo``.
"""

from softpend.rl.config import DQNConfig, MBPOConfig
from softpend.rl.training_log import TrainingLog

__all__ = ["DQNConfig", "MBPOConfig", "TrainingLog"]

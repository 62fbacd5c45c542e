"""The one home of the study's defaults and budgets.

The book's notebooks read their shared settings from here in their ``parameters`` cells (so that the full
profile of ``book/profiles.yml`` only lists what differs: nothing for the published figures, tiny budgets for
the quick profile), and the commands and benchmarks read the same values.  The physical defaults themselves
live in :class:`softpend.plant.RodParams` and :class:`softpend.task.Task`; the learning algorithms' settings
in :class:`softpend.rl.DQNConfig`, :class:`softpend.rl.MBPOConfig` and :class:`softpend.pilco.PilcoConfig`.
"""

from __future__ import annotations

from dataclasses import dataclass

from softpend.pilco.loop import PilcoConfig
from softpend.rl.config import DQNConfig, MBPOConfig
from softpend.task import Task

__all__ = ["PILCO", "PILCO_BOOK", "PilcoBudget", "REPORT_SEEDS", "RL_BOOK", "RL_EPISODES", "RLBudget", "SELECTION_SEEDS",
           "TASK"]

#: The task of every figure: the default rod on the PRB plant, hanging starts.
TASK = Task()


@dataclass(frozen=True)
class RLBudget:
    """The RL runs behind Figures 4-6 and 10 (and the RL rows of the beam chapter's transfer table).

    Parameters
    ----------
    episodes_dqn, episodes_mbpo : int
        Training episode budget per seed (real episodes for DQN-MBPO); a run stops earlier once it balances
        (:attr:`softpend.rl.DQNConfig.stop_after_balanced_evaluations`).
    seeds : tuple of int
        Training seeds.
    episode_s : float
        Training episode length [s] (the configs' default).
    rollouts_per_real_step : int
        DQN-MBPO model rollouts per real agent step (the config's default, the report's 9).
    mbpo_random_episodes : int
        Random-torque episodes before DQN-MBPO's first model fit (the config's default).
    runs_root : str
        Run folders (trained once, reused by every figure; other plants: ``<runs_root>-<plant>``).
    """

    episodes_dqn: int = 250
    episodes_mbpo: int = 80
    seeds: tuple[int, ...] = tuple(range(10))
    episode_s: float = DQNConfig.episode_s
    rollouts_per_real_step: int = MBPOConfig.rollouts_per_real_step
    mbpo_random_episodes: int = MBPOConfig.initial_random_episodes
    runs_root: str = "runs/rl-book"


#: The published RL budget.
RL_BOOK = RLBudget()

#: Training episodes of each RL method: the ``softpend train`` default, the book and the benchmark runs.
RL_EPISODES = {"dqn": RL_BOOK.episodes_dqn, "mbpo": RL_BOOK.episodes_mbpo}


#: The PILCO settings of Figure 10 (the :class:`~softpend.pilco.PilcoConfig` defaults).
PILCO = PilcoConfig()


@dataclass(frozen=True)
class PilcoBudget:
    """The PILCO runs of Figure 10.

    Parameters
    ----------
    seeds : tuple of int
        One PILCO run per seed.
    runs_root : str
        Run folders (other plants: ``<runs_root>-<plant>``).
    """

    seeds: tuple[int, ...] = tuple(range(10))
    runs_root: str = "runs/pilco-book"


#: The published PILCO budget.
PILCO_BOOK = PilcoBudget()


#: Start seeds that training and model selection see: the evaluations during training that pick an RL run's
#: best agent, stop its training and decide when PILCO has balanced (the configs' ``selection_seeds`` and
#: ``eval_seeds``).
SELECTION_SEEDS = tuple(sorted(set(DQNConfig().selection_seeds) | set(MBPOConfig().selection_seeds) | set(PILCO.eval_seeds)))

#: Fresh start seeds of every reported success rate and upright error: no training or selection step
#: evaluates on them (``tests/test_presets.py`` checks that they are disjoint from the seeds above and from
#: the training seeds).
REPORT_SEEDS = tuple(range(20_000, 20_020))

"""The training runs of several methods in one pool of workers.

Training one method after another leaves workers idle while each method's last runs finish; one pool over
all the runs keeps every worker busy until the last few.  :func:`train_in_one_pool` starts PILCO's runs first
(a run that never balances spends its whole budget, several times a typical run, and which one does is not
known beforehand), then DQN-MBPO's, then DQN's, the shortest, which fill the end.  The runs, their folders and
their reuse are those of :func:`softpend.study.head_to_head.pilco_runs` and
:func:`softpend.study.rl_runs.train_seeds`, which then find them finished: the pool changes when a run trains,
never what it computes.  :func:`train_book_runs` trains the runs of the book's Figures 4-6 and 10 (the
settings of :mod:`softpend.study.presets`) this way before the book's notebooks execute.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

from softpend.pilco.loop import PilcoConfig
from softpend.rl.config import DQNConfig
from softpend.study.head_to_head import pilco_jobs, run_and_save
from softpend.study.presets import PILCO, PILCO_BOOK, RL_BOOK, PilcoBudget, RLBudget
from softpend.study.rl_runs import figure_configs, rl_jobs, train_run
from softpend.study.sweep import call_job, run_jobs

__all__ = ["BOOK_RUN_SETS", "train_book_runs", "train_in_one_pool"]

#: The run sets a book notebook may declare it reads (front matter ``softpend: {book_runs: [...]}``).
BOOK_RUN_SETS = ("rl", "pilco")


def train_in_one_pool(rl_specs: Sequence[tuple[str, DQNConfig, Sequence[int], int]], rl_root: Path | str,
                      pilco_config: Optional[PilcoConfig] = None, pilco_seeds: Sequence[int] = (),
                      pilco_root: Path | str | None = None, workers: Optional[int] = None, progress: bool = True,
                      backend: Optional[str] = None) -> int:
    """Train every run still missing, RL and PILCO, in one pool; returns how many runs were trained.

    Parameters
    ----------
    rl_specs : sequence of (algo, config, seeds, episodes)
        The RL runs, as for :func:`softpend.study.rl_runs.train_seeds` (``algo`` ``"dqn"`` or ``"mbpo"``).
    rl_root : path
        Their run folders (``<rl_root>/<algo>-seed<k>``).
    pilco_config : PilcoConfig, optional
        PILCO's settings (its seed is replaced by each of ``pilco_seeds``); None: no PILCO runs.
    pilco_seeds : sequence of int
        One PILCO run per seed.
    pilco_root : path, optional
        Their run folders (``<pilco_root>/pilco-seed<k>``); default ``rl_root``.
    workers, progress, backend
        As for :func:`softpend.study.sweep.run_jobs`.
    """
    jobs = []
    if pilco_config is not None and len(pilco_seeds):
        root = Path(rl_root if pilco_root is None else pilco_root)
        jobs += [(name, (run_and_save, *args)) for name, args in pilco_jobs(pilco_config, pilco_seeds, root)]
    if rl_specs:
        jobs += [(name, (train_run, *args)) for name, args in rl_jobs(rl_specs, rl_root)]
    run_jobs(call_job, [args for _, args in jobs], [name for name, _ in jobs], workers, progress,
             desc="training runs", backend=backend)
    return len(jobs)


def train_book_runs(run_sets: Sequence[str] = BOOK_RUN_SETS, root: Path | str = ".", workers: Optional[int] = None,
                    progress: bool = True, rl_budget: RLBudget = RL_BOOK, pilco_config: PilcoConfig = PILCO,
                    pilco_budget: PilcoBudget = PILCO_BOOK) -> int:
    """Train the book's runs of ``run_sets`` (``"rl"``: DQN and DQN-MBPO of Figures 4-6, ``"pilco"``: PILCO of
    Figure 10) in one pool, in their run folders under ``root`` (the project root, where the notebooks
    execute); returns how many runs were trained.  The settings are the notebooks' defaults, so a notebook
    executed with them finds its runs finished."""
    unknown = sorted(set(run_sets) - set(BOOK_RUN_SETS))
    if unknown:
        raise ValueError(f"run_sets must be among {list(BOOK_RUN_SETS)}, got {unknown}")
    rl_specs = []
    if "rl" in run_sets:
        configs = figure_configs(episode_s=rl_budget.episode_s, rollouts_per_real_step=rl_budget.rollouts_per_real_step,
                                 mbpo_random_episodes=rl_budget.mbpo_random_episodes)
        rl_specs = [("dqn", configs["dqn"], rl_budget.seeds, rl_budget.episodes_dqn),
                    ("mbpo", configs["mbpo"], rl_budget.seeds, rl_budget.episodes_mbpo)]
    pilco = "pilco" in run_sets
    return train_in_one_pool(rl_specs, Path(root) / rl_budget.runs_root, pilco_config if pilco else None,
                             pilco_budget.seeds if pilco else (), Path(root) / pilco_budget.runs_root,
                             workers=workers, progress=progress)

"""The training runs of several methods in one pool of workers.

Training one method after another leaves workers idle while each method's last runs finish; one pool over
all the runs keeps every worker busy until the last few.  :func:`train_in_one_pool` starts PILCO's runs first
(a run that never balances spends its whole budget, several times a typical run, and which one does is not
known beforehand), then DQN-MBPO's, then DQN's, the shortest, which fill the end.  The runs, their folders and
their reuse are those of :func:`softpend.study.head_to_head.pilco_runs` and
:func:`softpend.study.rl_runs.train_seeds`, which then find them finished: the pool changes when a run trains,
never what it computes.  :func:`train_book_runs` trains the runs of the book's Figures 4-6 and 10 (the
settings of :mod:`softpend.study.presets`) this way for the book's notebooks: :func:`book_run_jobs` lists the
runs still missing, :func:`book_run_names` the runs a notebook's run set comprises, so that the book runner can
execute a notebook as soon as its own runs have finished.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Optional, Sequence

from softpend.pilco.loop import PilcoConfig
from softpend.rl.config import DQNConfig
from softpend.study.head_to_head import pilco_jobs, run_and_save
from softpend.study.presets import PILCO, PILCO_BOOK, RL_BOOK, PilcoBudget, RLBudget
from softpend.study.rl_runs import figure_configs, rl_jobs, train_run
from softpend.study.sweep import call_job, run_jobs

__all__ = ["BOOK_RUN_SETS", "book_run_jobs", "book_run_names", "train_book_runs", "train_in_one_pool", "train_jobs"]

#: The run sets a book notebook may declare it reads (front matter ``softpend: {book_runs: [...]}``): ``"rl"``,
#: DQN and DQN-MBPO over the book's seeds (Figures 4-6); ``"pilco"``, PILCO over its seeds (Figure 10);
#: ``"first_seed"``, the three methods' runs of the first book seed (the learned controllers of the rig chapter).
BOOK_RUN_SETS = ("rl", "pilco", "first_seed")

#: A job of :func:`train_jobs`: ``(name, (function, *arguments))``, the name being the run's folder name.
Job = tuple[str, tuple[Any, ...]]


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
    return train_jobs(_pool_jobs(rl_specs, rl_root, pilco_config, pilco_seeds, pilco_root), workers=workers,
                      progress=progress, backend=backend)


def _pool_jobs(rl_specs: Sequence[tuple[str, DQNConfig, Sequence[int], int]], rl_root: Path | str,
               pilco_config: Optional[PilcoConfig], pilco_seeds: Sequence[int],
               pilco_root: Path | str | None) -> list[Job]:
    """The missing runs of :func:`train_in_one_pool`'s arguments, PILCO's first, then DQN-MBPO's, then DQN's."""
    jobs: list[Job] = []
    if pilco_config is not None and len(pilco_seeds):
        root = Path(rl_root if pilco_root is None else pilco_root)
        jobs += [(name, (run_and_save, *args)) for name, args in pilco_jobs(pilco_config, pilco_seeds, root)]
    if rl_specs:
        jobs += [(name, (train_run, *args)) for name, args in rl_jobs(rl_specs, rl_root)]
    return jobs


def train_jobs(jobs: Sequence[Job], workers: Optional[int] = None, progress: bool = True,
               backend: Optional[str] = None, on_finished: Optional[Callable[[str], None]] = None,
               background: bool = False) -> int:
    """Run ``jobs`` (from :func:`book_run_jobs`, in their order) in one pool; returns how many.

    ``workers``, ``progress``, ``backend``, ``on_finished`` (called with each run's name as it finishes) and
    ``background`` (the workers take only what other work leaves of the processors) are those of
    :func:`softpend.study.sweep.run_jobs`.
    """
    if jobs:
        run_jobs(call_job, [args for _, args in jobs], [name for name, _ in jobs], workers, progress,
                 desc="training runs", backend=backend, on_finished=on_finished, background=background)
    return len(jobs)


def _check_run_sets(run_sets: Sequence[str]) -> None:
    unknown = sorted(set(run_sets) - set(BOOK_RUN_SETS))
    if unknown:
        raise ValueError(f"run_sets must be among {list(BOOK_RUN_SETS)}, got {unknown}")


def book_run_names(run_sets: Sequence[str], rl_budget: RLBudget = RL_BOOK,
                   pilco_budget: PilcoBudget = PILCO_BOOK) -> frozenset[str]:
    """The folder names (``dqn-seed0``, ...) of the runs that ``run_sets`` comprise, trained or not."""
    _check_run_sets(run_sets)
    names: set[str] = set()
    if "rl" in run_sets:
        names |= {f"{algo}-seed{seed}" for algo in ("dqn", "mbpo") for seed in rl_budget.seeds}
    if "pilco" in run_sets:
        names |= {f"pilco-seed{seed}" for seed in pilco_budget.seeds}
    if "first_seed" in run_sets:
        names |= {f"{method}-seed{rl_budget.seeds[0]}" for method in ("dqn", "mbpo", "pilco")}
    return frozenset(names)


def book_run_jobs(run_sets: Sequence[str] = BOOK_RUN_SETS, root: Path | str = ".", rl_budget: RLBudget = RL_BOOK,
                  pilco_config: PilcoConfig = PILCO, pilco_budget: PilcoBudget = PILCO_BOOK) -> list[Job]:
    """The runs of ``run_sets`` (:data:`BOOK_RUN_SETS`) still missing in their run folders under ``root``
    (the project root, where the notebooks execute), in the order to start them: PILCO's, then DQN-MBPO's,
    then DQN's (:func:`train_in_one_pool`).  The settings are the notebooks' defaults, so a notebook executed
    with them finds its runs finished."""
    _check_run_sets(run_sets)
    first = rl_budget.seeds[0]
    rl_seeds = list(rl_budget.seeds) if "rl" in run_sets else [first] if "first_seed" in run_sets else []
    pilco_seeds = list(pilco_budget.seeds) if "pilco" in run_sets else []
    if "first_seed" in run_sets and first not in pilco_seeds:
        pilco_seeds.insert(0, first)
    rl_specs = []
    if rl_seeds:
        configs = figure_configs(episode_s=rl_budget.episode_s, rollouts_per_real_step=rl_budget.rollouts_per_real_step,
                                 mbpo_random_episodes=rl_budget.mbpo_random_episodes)
        rl_specs = [("dqn", configs["dqn"], rl_seeds, rl_budget.episodes_dqn),
                    ("mbpo", configs["mbpo"], rl_seeds, rl_budget.episodes_mbpo)]
    return _pool_jobs(rl_specs, Path(root) / rl_budget.runs_root, pilco_config if pilco_seeds else None, pilco_seeds,
                      Path(root) / pilco_budget.runs_root)


def train_book_runs(run_sets: Sequence[str] = BOOK_RUN_SETS, root: Path | str = ".", workers: Optional[int] = None,
                    progress: bool = True, rl_budget: RLBudget = RL_BOOK, pilco_config: PilcoConfig = PILCO,
                    pilco_budget: PilcoBudget = PILCO_BOOK) -> int:
    """Train the book's runs of ``run_sets`` (:data:`BOOK_RUN_SETS`) still missing under ``root`` in one pool
    (:func:`book_run_jobs`); returns how many runs were trained."""
    return train_jobs(book_run_jobs(run_sets, root, rl_budget, pilco_config, pilco_budget), workers=workers,
                      progress=progress)

"""The training runs of several methods in one pool of workers, and the runs the book's notebooks read.

Training one method after another leaves workers idle while each method's last runs finish; one pool over all
the runs (:func:`softpend.study.sweep.run_jobs`) keeps every worker busy until the last few.
:func:`train_in_one_pool` starts PILCO's runs first (a run that never balances spends its whole budget), then
DQN-MBPO's, then DQN's, the shortest, which fill the end.  The runs, their folders and their reuse are those of
:func:`softpend.study.rl_runs.train_seeds` and :func:`softpend.study.head_to_head.pilco_runs`, which then find
them finished: the pool changes when a run trains, never what it computes.  :func:`train_book` (``softpend sweep
--book``, the first step of ``make book``) trains the runs that the book's notebooks read under a profile, so
that ``softpend book`` only executes notebooks.
"""

from __future__ import annotations

import datetime
import time
from pathlib import Path
from typing import Any, Optional, Sequence

from softpend.io.outputs import atomic_write, json_text
from softpend.io.overrides import apply_overrides
from softpend.study.book import BookLayout, front_matter, load_profiles, read_notebook, toc_notebooks
from softpend.study.head_to_head import pilco_jobs, run_and_save
from softpend.study.presets import PILCO_BOOK, RL_BOOK, TASK, load_hparams
from softpend.study.rl_runs import figure_configs, rl_jobs, train_run
from softpend.study.sweep import call_job, default_workers, run_jobs
from softpend.task import Task

__all__ = ["BOOK_RUN_SETS", "book_jobs", "book_run_jobs", "train_book", "train_in_one_pool"]

#: A job of the pool: ``(name, (function, *arguments))``.
Job = tuple[str, tuple[Any, ...]]


def _order(jobs: Sequence[Job]) -> list[Job]:
    """PILCO's runs first (one that never balances spends its whole budget), then DQN-MBPO's, then DQN's, the
    shortest, which fill the end; a name's last part is ``<method>-seed<k>``."""
    rank = {"pilco": 0, "mbpo": 1, "dqn": 2}
    return sorted(jobs, key=lambda job: rank.get(job[0].rsplit("/", 1)[-1].split("-")[0], 3))


def train_in_one_pool(
    rl_specs: Sequence[tuple[str, Any, Sequence[int], int]],
    rl_root: Path | str,
    pilco_config: Any = None,
    pilco_seeds: Sequence[int] = (),
    pilco_root: Path | str | None = None,
    workers: Optional[int] = None,
    progress: bool = True,
    backend: Optional[str] = None,
) -> int:
    """Train every run still missing, RL (``(algo, config, seeds, episodes)`` each, as for
    :func:`softpend.study.rl_runs.train_seeds`, under ``rl_root``) and PILCO (``pilco_config`` with each of
    ``pilco_seeds``, under ``pilco_root``, default ``rl_root``), in one pool; returns how many were trained.  The
    runs and folders are those of ``train_seeds`` and :func:`softpend.study.head_to_head.pilco_runs`, which then
    find them finished."""
    jobs: list[Job] = []
    if pilco_config is not None and len(pilco_seeds):
        root = Path(rl_root if pilco_root is None else pilco_root)
        jobs += [(name, (run_and_save, *args)) for name, args in pilco_jobs(pilco_config, pilco_seeds, root)]
    if rl_specs:
        jobs += [(name, (train_run, *args)) for name, args in rl_jobs(rl_specs, rl_root)]
    return _train(_order(jobs), workers, progress, backend)


def _train(jobs: Sequence[Job], workers: Optional[int], progress: bool, backend: Optional[str]) -> int:
    if jobs:
        run_jobs(
            call_job,
            [args for _, args in jobs],
            [name for name, _ in jobs],
            workers,
            progress,
            desc="training runs",
            backend=backend,
        )
    return len(jobs)


#: The run sets a book notebook may read (front matter ``softpend: {book_runs: [...]}``): ``"rl"``, DQN and
#: DQN-MBPO over the book's seeds (Figures 4-6); ``"pilco"``, PILCO over its seeds (Figure 10); ``"first_seed"``,
#: the three methods' runs of the first seed (the learned controllers of the rig chapter).
BOOK_RUN_SETS = ("rl", "pilco", "first_seed")


def book_run_jobs(
    run_sets: Sequence[str],
    root: Path | str = ".",
    parameters: Optional[dict[str, Any]] = None,
    claimed: Optional[set[str]] = None,
) -> list[Job]:
    """The runs of ``run_sets`` still missing under ``root``, named by folder (``runs/rl-book/dqn-seed0``), with
    the settings the notebooks that read them train with (:mod:`softpend.study.presets`, ``book/hparams``), the
    training parameters of ``parameters`` (a notebook's profile values: ``episodes_dqn``, ``episodes_mbpo``,
    ``seeds``, ``runs_root``, ``rl_overrides``, ``pilco_seeds``, ``pilco_runs_root``, ``pilco_overrides``,
    ``task_overrides``) in their place.  The plant is the book's (``--set plant=...`` runs train in the notebooks).
    A folder in ``claimed`` (those an earlier notebook reads, finished or not) is left to it; this call's folders
    are added to ``claimed``."""
    if not isinstance(run_sets, (list, tuple)) or not set(run_sets) <= set(BOOK_RUN_SETS):
        raise ValueError(f"run sets (softpend.book_runs) must be a list among {list(BOOK_RUN_SETS)}, got {run_sets!r}")
    given = dict(parameters or {})
    seeds, task_overrides = list(given.get("seeds", RL_BOOK.seeds)), given.get("task_overrides") or {}
    rl_seeds = seeds if "rl" in run_sets else seeds[:1] if "first_seed" in run_sets else []
    pilco_seeds = list(given.get("pilco_seeds", PILCO_BOOK.seeds)) if "pilco" in run_sets else []
    if "first_seed" in run_sets and seeds[0] not in pilco_seeds:
        pilco_seeds.insert(0, seeds[0])
    claimed = set() if claimed is None else claimed

    def fresh(folder: str, method: str, seeds: Sequence[int]) -> list[int]:  # and claim them
        names = {seed: f"{folder}/{method}-seed{seed}" for seed in seeds}
        kept = [seed for seed in dict.fromkeys(seeds) if names[seed] not in claimed]
        claimed.update(names.values())
        return kept

    jobs: list[Job] = []
    pilco_root = str(given.get("pilco_runs_root", PILCO_BOOK.runs_root))
    if pilco_seeds := fresh(pilco_root, "pilco", pilco_seeds):
        config = load_hparams(
            "pilco", apply_overrides(Task(plant=TASK.plant), task_overrides), given.get("pilco_overrides")
        )
        jobs += [
            (f"{pilco_root}/{name}", (run_and_save, *args))
            for name, args in pilco_jobs(config, pilco_seeds, Path(root) / pilco_root)
        ]
    rl_root = str(given.get("runs_root", RL_BOOK.runs_root))
    if rl_seeds:
        configs = figure_configs(task_overrides=task_overrides, rl_overrides=given.get("rl_overrides"))
        specs = [
            (algo, configs[algo], kept, given.get(f"episodes_{algo}", getattr(RL_BOOK, f"episodes_{algo}")))
            for algo in ("dqn", "mbpo")
            if (kept := fresh(rl_root, algo, rl_seeds))
        ]
        jobs += [(f"{rl_root}/{name}", (train_run, *args)) for name, args in rl_jobs(specs, Path(root) / rl_root)]
    return _order(jobs)


def book_jobs(root: Path | str = ".", profile: str = "full") -> list[Job]:
    """The training runs still missing that the book's notebooks read under ``profile``: for every toc notebook
    with ``softpend: {book_runs: [...]}``, :func:`book_run_jobs` with its profile parameters; a folder that two
    notebooks read is the first's in toc order (the rig chapter reads Figure 4's runs with their settings)."""
    layout = BookLayout.at(root)
    toc, profiles = toc_notebooks(layout.toc_path), load_profiles(layout.profiles_path)
    if profile not in profiles:
        raise ValueError(f"unknown profile {profile!r}; {layout.profiles_path} defines {sorted(profiles)}")
    jobs: list[Job] = []
    claimed: set[str] = set()
    for name in toc:
        run_sets = front_matter(read_notebook(layout.source_path(name)), name, toc)["book_runs"]
        try:
            jobs += book_run_jobs(run_sets, layout.root, profiles[profile].get(name), claimed) if run_sets else []
        except ValueError as exc:
            raise ValueError(f"notebook {name!r}: {exc}") from None
    return _order(jobs)


def train_book(
    root: Path | str = ".",
    profile: str = "full",
    workers: Optional[int] = None,
    progress: bool = True,
    backend: Optional[str] = None,
) -> dict[str, Any]:
    """Train :func:`book_jobs` in one pool and record what was trained, in how long, in
    ``book/_generated/training.json`` (the execution page shows it); returns that record."""
    jobs, start = book_jobs(root, profile), time.perf_counter()
    workers = default_workers() if workers is None else workers
    _train(jobs, workers, progress, backend)
    record = {
        "profile": profile,
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "trained": [name for name, _ in jobs],
        "seconds": time.perf_counter() - start,
        "workers": workers,
    }
    layout = BookLayout.at(root)
    layout.generated_dir.mkdir(parents=True, exist_ok=True)
    with atomic_write(layout.training_path, "w") as handle:
        handle.write(json_text(record, indent=2) + "\n")
    return record

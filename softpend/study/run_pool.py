"""The training runs of several methods in one pool of workers, and the runs the book's notebooks read
(``softpend sweep --book``)."""

from __future__ import annotations

import datetime
import posixpath
import time
from pathlib import Path
from typing import Any, Optional, Sequence

from softpend.io.outputs import atomic_write, json_text
from softpend.io.overrides import apply_overrides
from softpend.study.book import BookLayout, book_profile, front_matter, read_notebook
from softpend.study.head_to_head import pilco_jobs, run_and_save
from softpend.study.presets import PILCO_BOOK, RL_BOOK, TASK, load_hparams
from softpend.study.rl_runs import figure_configs, rl_jobs, train_run
from softpend.study.sweep import call_job, default_workers, run_jobs
from softpend.task import Task

#: A job of the pool: ``(name, (function, *arguments))``.
Job = tuple[str, tuple[Any, ...]]
#: The run sets a notebook may read (front matter ``softpend: {book_runs: [...]}``).
BOOK_RUN_SETS = ("rl", "pilco", "first_seed")


def train_in_one_pool(
    rl_specs: Sequence, root: Path | str, pilco_config: Any = None, pilco_seeds: Sequence = (), **pool
) -> int:
    """Train the missing runs of ``rl_specs`` (``(algo, config, seeds, episodes)`` each) and of ``pilco_config`` over
    ``pilco_seeds`` under ``root`` in one pool (``pool``: ``workers``, ``progress``, ``backend``); returns their number."""
    return _train(_jobs(root, ("", ""), pilco_config, pilco_seeds, rl_specs), **pool)


def _jobs(
    root: Path | str, folders: tuple[str, str], pilco_config: Any, pilco_seeds: Sequence, rl_specs: Sequence
) -> list[Job]:
    """The missing runs of ``pilco_config`` over ``pilco_seeds`` and of ``rl_specs`` under ``root``, in ``folders``
    (PILCO's, the RL methods'), as pool jobs named by folder: PILCO's first (the longest), then DQN-MBPO's, then DQN's."""
    pilco_folder, rl_folder = folders
    pilco = pilco_jobs(pilco_config, pilco_seeds, Path(root, pilco_folder)) if pilco_config is not None else []
    jobs = [(posixpath.join(pilco_folder, n), (run_and_save, *a)) for n, a in pilco]
    return jobs + [(posixpath.join(rl_folder, n), (train_run, *a)) for n, a in rl_jobs(rl_specs, Path(root, rl_folder))]


def _train(jobs: Sequence[Job], workers: Optional[int] = None, progress: bool = True, backend=None) -> int:
    if jobs:
        run_jobs(call_job, [a for _, a in jobs], [n for n, _ in jobs], workers, progress, "training runs", backend)
    return len(jobs)


def book_run_jobs(
    run_sets: Sequence[str],
    root: Path | str = ".",
    parameters: Optional[dict[str, Any]] = None,
    claimed: Optional[set[str]] = None,
) -> list[Job]:
    """The missing runs of ``run_sets`` under ``root``, named by folder, as the notebooks train them under a profile's
    ``parameters`` (``seeds``, ``runs_root``, ``rl_overrides``, ...); folders in ``claimed`` are left out, and this
    call's are added to it."""
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
        kept = [seed for seed in seeds if names[seed] not in claimed]
        claimed.update(names.values())
        return kept

    folders = (str(given.get("pilco_runs_root", PILCO_BOOK.runs_root)), str(given.get("runs_root", RL_BOOK.runs_root)))
    pilco_config = None
    if pilco_seeds := fresh(folders[0], "pilco", pilco_seeds):
        task = apply_overrides(Task(plant=TASK.plant), task_overrides)
        pilco_config = load_hparams("pilco", task, given.get("pilco_overrides"))
    configs = figure_configs(task_overrides=task_overrides, rl_overrides=given.get("rl_overrides")) if rl_seeds else {}
    specs = [
        (algo, configs[algo], kept, given.get(f"episodes_{algo}", getattr(RL_BOOK, f"episodes_{algo}")))
        for algo in ("dqn", "mbpo")
        if (kept := fresh(folders[1], algo, rl_seeds))
    ]
    return _jobs(root, folders, pilco_config, pilco_seeds, specs)


def book_jobs(root: Path | str = ".", profile: str = "full") -> list[Job]:
    """The missing runs that the toc's notebooks read under ``profile`` (:func:`book_run_jobs` per notebook), PILCO's
    first (the longest), then DQN-MBPO's, then DQN's (a name ends with ``<method>-<hash>-seed<k>``)."""
    layout, toc, given = book_profile(root, profile)
    jobs, claimed = list[Job](), set[str]()
    for name in toc:
        run_sets = front_matter(read_notebook(layout.source_path(name)), name, toc)["book_runs"]
        try:
            jobs += book_run_jobs(run_sets, layout.root, given.get(name), claimed) if run_sets else []
        except ValueError as exc:
            raise ValueError(f"notebook {name!r}: {exc}") from None
    rank = {"pilco": 0, "mbpo": 1, "dqn": 2}
    return sorted(jobs, key=lambda job: rank[job[0].rsplit("/", 1)[-1].split("-")[0]])


def train_book(root: Path | str = ".", profile: str = "full", workers: Optional[int] = None, backend=None) -> dict:
    """Train :func:`book_jobs` in one pool and write (and return) the record the execution page shows."""
    jobs, start = book_jobs(root, profile), time.perf_counter()
    workers = default_workers() if workers is None else workers
    _train(jobs, workers, True, backend)
    seconds = time.perf_counter() - start
    date = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    record = dict(profile=profile, date=date, trained=[name for name, _ in jobs], seconds=seconds, workers=workers)
    layout = BookLayout.at(root)
    layout.generated_dir.mkdir(parents=True, exist_ok=True)
    with atomic_write(layout.training_path, "w") as handle:
        handle.write(json_text(record, indent=2) + "\n")
    return record

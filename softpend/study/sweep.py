"""Independent runs (methods x seeds) on a parallel engine: joblib's ``loky`` process pool by default, Ray or
Dask when installed and asked for.

The book's figures and ``softpend sweep`` rest on runs that each use one core (torch is held to one thread in
every worker) and write their results to their own folder.  :func:`run_jobs` hands such jobs to
:class:`joblib.Parallel`; the workers return nothing but a status, and the caller reads the results back from
disk, so no result crosses a process boundary as a pickle and a finished run is kept whatever happens to the
others.  A job that raises is reported by name (its run is deterministic, so it is not run again); a job
whose worker process dies is retried (``retries`` times); the runs that finished are never run again.

A job's numbers do not depend on where it runs: each run seeds everything it draws from its own seed, and a
test checks that runs trained through the engine equal the same runs trained in the calling process.

Every method's runs share one pool (:func:`train_in_one_pool`), so that no worker idles while one method's last
runs finish.  :func:`train_book` (``softpend sweep --book``) trains the runs the book's notebooks read, for one
profile of ``book/profiles.yml``, before ``softpend book`` executes them.

Backends
--------
``"loky"`` (default; joblib's robust process pool, started fresh, so a script that sweeps needs no
``if __name__ == "__main__":`` guard for the workers' sake), ``"ray"`` (``ray.util.joblib``; connects to
a running cluster through ``RAY_ADDRESS`` or starts a local one), ``"dask"`` (``dask.distributed``: the
client of ``DASK_SCHEDULER_ADDRESS`` or a local cluster).  ``$SOFTPEND_BACKEND`` picks the default and
``$SOFTPEND_WORKERS`` caps the number of workers (``1`` runs every job in the calling process).
"""

from __future__ import annotations

import contextlib
import os
import traceback
import warnings
from pathlib import Path
from typing import Any, Callable, Iterator, Optional, Sequence

__all__ = ["BACKENDS", "BOOK_RUN_SETS", "SweepFailed", "book_jobs", "book_run_jobs", "call_job", "default_backend",
           "default_workers", "run_jobs", "train_book", "train_in_one_pool"]

#: Environment variable that caps the number of workers (``1`` runs every job in the caller).
WORKERS_ENV = "SOFTPEND_WORKERS"
#: Environment variable that picks the default backend.
BACKEND_ENV = "SOFTPEND_BACKEND"
#: Backends :func:`run_jobs` accepts.
BACKENDS = ("loky", "ray", "dask")


class SweepFailed(RuntimeError):
    """Some jobs failed after every retry; ``failures`` maps each job's name to its last error (the other
    jobs finished and their results are on disk)."""

    def __init__(self, desc: str, failures: dict[str, str]) -> None:
        names = ", ".join(repr(n) for n in failures)
        last = next(iter(failures.values())).strip().splitlines()[-1] if failures else ""
        super().__init__(f"{desc}: job(s) {names} failed ({last})")
        self.failures = failures


def default_workers() -> int:
    """Workers to use: ``$SOFTPEND_WORKERS`` if set, else the CPU cores this process may use."""
    value = os.environ.get(WORKERS_ENV)
    if value is not None:
        try:
            workers = int(value)
        except ValueError:
            raise ValueError(f"{WORKERS_ENV} must be a positive integer, got {value!r}") from None
        if workers < 1:
            raise ValueError(f"{WORKERS_ENV} must be a positive integer, got {value!r}")
        return workers
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def default_backend() -> str:
    """``$SOFTPEND_BACKEND`` if set (checked), else ``"loky"``."""
    backend = os.environ.get(BACKEND_ENV, "loky")
    if backend not in BACKENDS:
        raise ValueError(f"{BACKEND_ENV} must be one of {list(BACKENDS)}, got {backend!r}")
    return backend


def _guarded(job: Callable[..., None], args: tuple[Any, ...], name: str, progress: bool,
             one_thread: bool = True) -> tuple[str, Optional[str]]:
    """Run one job (in a worker: with one torch thread, see :func:`run_jobs`);
    ``(name, None)`` on success, ``(name, traceback)`` if it raised (an exception never crosses back as a
    pickled object)."""
    if one_thread:
        import torch

        torch.set_num_threads(1)
    try:
        job(*args, progress=progress)
    except Exception:  # noqa: BLE001 -- reported by name to the caller, which retries or raises
        return name, traceback.format_exc()
    return name, None


@contextlib.contextmanager
def _engine(backend: str) -> Iterator[None]:
    """Make ``backend`` joblib's active backend (registering Ray's or Dask's first)."""
    import joblib

    if backend == "loky":
        yield
        return
    if backend == "ray":
        try:
            from ray.util.joblib import register_ray
        except ImportError:
            raise ValueError("backend 'ray' needs the ray package (pip install 'ray[default]')") from None
        register_ray()
        with joblib.parallel_config(backend="ray"):
            yield
        return
    try:
        from dask.distributed import Client
    except ImportError:
        raise ValueError("backend 'dask' needs dask.distributed (pip install 'dask[distributed]')") from None
    address = os.environ.get("DASK_SCHEDULER_ADDRESS")
    with Client(address) if address else Client(processes=True), joblib.parallel_config(backend="dask"):
        yield


def run_jobs(
    job: Callable[..., None],
    jobs: Sequence[tuple[Any, ...]],
    names: Sequence[str],
    workers: Optional[int] = None,
    progress: bool = True,
    desc: str = "runs",
    backend: Optional[str] = None,
    retries: int = 1,
) -> None:
    """Call ``job(*args)`` for every ``args`` in ``jobs`` on the parallel engine, retrying failures.

    Parameters
    ----------
    job : callable
        A module-level function (workers import it by name) that writes its results to disk.  It is called
        as ``job(*args, progress=...)``: with this function's ``progress`` in this process, ``False`` in a
        worker.
    jobs : sequence of tuples
        The arguments of each call, in the order to start them (put the longest first).
    names : sequence of str
        One distinct name per job, used in the progress bar and in errors.
    workers : int, optional
        Workers to use; default :func:`default_workers`.  With 1 (or a single job) the calls run one after
        another in this process.
    progress : bool
        Show a bar over finished jobs (only when jobs run in workers).
    desc : str
        Label of the progress bar and of errors.
    backend : {"loky", "ray", "dask"}, optional
        The engine (default :func:`default_backend`).
    retries : int
        How often a job whose worker died is run again before giving up (a job that raised is not retried:
        it would raise again).

    Raises
    ------
    SweepFailed
        Naming every job that still failed after ``retries`` retries; all other jobs have finished.
    ValueError
        On inconsistent arguments or an unavailable backend.
    """
    if len(jobs) != len(names):
        raise ValueError(f"got {len(jobs)} jobs but {len(names)} names")
    if len(set(names)) != len(names):
        raise ValueError(f"job names must be distinct, got {list(names)}")
    workers = default_workers() if workers is None else workers
    if isinstance(workers, bool) or int(workers) != workers or workers < 1:
        raise ValueError(f"workers must be an integer >= 1, got {workers!r}")
    if isinstance(retries, bool) or int(retries) != retries or retries < 0:
        raise ValueError(f"retries must be an integer >= 0, got {retries!r}")
    backend = default_backend() if backend is None else backend
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {list(BACKENDS)}, got {backend!r}")
    workers = min(int(workers), max(1, len(jobs)))
    pending = dict(zip(names, jobs))
    failures: dict[str, str] = {}
    for attempt in range(int(retries) + 1):
        raised, lost = _run_round(job, pending, workers, progress, desc + (f" (retry {attempt})" if attempt else ""),
                                  backend)
        failures.update(raised)
        pending = {name: pending[name] for name in lost}
        if not pending:
            break
    failures.update({name: LOST for name in pending})
    if failures:
        raise SweepFailed(desc, failures)


def call_job(job: Callable[..., None], *args: Any, progress: bool = True) -> None:
    """Call ``job(*args, progress=progress)``: the job function of a :func:`run_jobs` pool whose jobs call
    different functions (each argument tuple starts with its own module-level function)."""
    job(*args, progress=progress)


#: The error of a job whose worker process died (after every retry).
LOST = "its worker process died (killed, out of memory or crashed)"


def _run_round(job: Callable[..., None], pending: dict[str, tuple[Any, ...]], workers: int, progress: bool, desc: str,
               backend: str) -> tuple[dict[str, str], set[str]]:
    """One pass over ``pending``: ``(name -> traceback of the jobs that raised, names of the jobs whose worker
    died)``."""
    if workers <= 1:
        raised = {}
        for name, args in pending.items():
            _, error = _guarded(job, args, name, progress, one_thread=False)
            if error is not None:
                raised[name] = error
        return raised, set()

    import joblib
    from tqdm.auto import tqdm

    finished: set[str] = set()
    raised: dict[str, str] = {}
    try:
        # loky's check after a job takes a worker's growth past 300 MB (PILCO's) for a leak and starts a fresh
        # worker for the next job (no job is lost): no warning for that
        warnings.filterwarnings("ignore", message="A worker stopped while some jobs were given to the executor",
                                category=UserWarning, module="joblib")
        with _engine(backend):
            parallel = joblib.Parallel(n_jobs=min(workers, len(pending)), return_as="generator_unordered",
                                       **({"backend": "loky"} if backend == "loky" else {}))
            calls = (joblib.delayed(_guarded)(job, args, name, False, True)
                     for name, args in pending.items())
            with tqdm(total=len(pending), desc=desc, unit="run", disable=not progress) as bar:
                for name, error in parallel(calls):
                    finished.add(name)
                    if error is not None:
                        raised[name] = error
                    bar.set_postfix_str(name)
                    bar.update(1)
    except ValueError:
        raise
    except Exception:  # noqa: BLE001 -- a worker died (loky's TerminatedWorkerError, a lost Ray/Dask task)
        pass
    return raised, {name for name in pending if name not in finished}


# --------------------------------------------------------------------------- every method in one pool, the book's runs
#: A job of the pool: ``(name, (function, *arguments))``.
Job = tuple[str, tuple[Any, ...]]


def _order(jobs: Sequence[Job]) -> list[Job]:
    """PILCO's runs first (one that never balances spends its whole budget), then DQN-MBPO's, then DQN's, the
    shortest, which fill the end; a name's last part is ``<method>-seed<k>``."""
    rank = {"pilco": 0, "mbpo": 1, "dqn": 2}
    return sorted(jobs, key=lambda job: rank.get(job[0].rsplit("/", 1)[-1].split("-")[0], 3))


def train_in_one_pool(rl_specs: Sequence[tuple[str, Any, Sequence[int], int]], rl_root: Path | str,
                      pilco_config: Any = None, pilco_seeds: Sequence[int] = (), pilco_root: Path | str | None = None,
                      workers: Optional[int] = None, progress: bool = True, backend: Optional[str] = None) -> int:
    """Train every run still missing, RL (``(algo, config, seeds, episodes)`` each, as for
    :func:`softpend.study.rl_runs.train_seeds`, under ``rl_root``) and PILCO (``pilco_config`` with each of
    ``pilco_seeds``, under ``pilco_root``, default ``rl_root``), in one pool; returns how many were trained.  The
    runs and folders are those of ``train_seeds`` and :func:`softpend.study.head_to_head.pilco_runs`, which then
    find them finished."""
    from softpend.study.head_to_head import pilco_jobs, run_and_save
    from softpend.study.rl_runs import rl_jobs, train_run

    jobs: list[Job] = []
    if pilco_config is not None and len(pilco_seeds):
        root = Path(rl_root if pilco_root is None else pilco_root)
        jobs += [(name, (run_and_save, *args)) for name, args in pilco_jobs(pilco_config, pilco_seeds, root)]
    if rl_specs:
        jobs += [(name, (train_run, *args)) for name, args in rl_jobs(rl_specs, rl_root)]
    return _train(_order(jobs), workers, progress, backend)


def _train(jobs: Sequence[Job], workers: Optional[int], progress: bool, backend: Optional[str]) -> int:
    if jobs:
        run_jobs(call_job, [args for _, args in jobs], [name for name, _ in jobs], workers, progress,
                 desc="training runs", backend=backend)
    return len(jobs)


#: The run sets a book notebook may read (front matter ``softpend: {book_runs: [...]}``): ``"rl"``, DQN and
#: DQN-MBPO over the book's seeds (Figures 4-6); ``"pilco"``, PILCO over its seeds (Figure 10); ``"first_seed"``,
#: the three methods' runs of the first seed (the learned controllers of the rig chapter).
BOOK_RUN_SETS = ("rl", "pilco", "first_seed")


def book_run_jobs(run_sets: Sequence[str], root: Path | str = ".", parameters: Optional[dict[str, Any]] = None
                  ) -> list[Job]:
    """The runs of ``run_sets`` still missing under ``root``, named by folder (``runs/rl-book/dqn-seed0``), with
    the settings the notebooks that read them train with (:mod:`softpend.study.presets`, ``book/hparams``), the
    training parameters of ``parameters`` (a notebook's profile values: ``episodes_dqn``, ``episodes_mbpo``,
    ``seeds``, ``runs_root``, ``rl_overrides``, ``pilco_seeds``, ``pilco_runs_root``, ``pilco_overrides``,
    ``task_overrides``) in their place.  The plant is the book's (``--set plant=...`` runs train in the notebooks)."""
    from softpend.io.overrides import apply_overrides
    from softpend.study.head_to_head import pilco_jobs, run_and_save
    from softpend.study.presets import PILCO_BOOK, RL_BOOK, TASK, load_hparams
    from softpend.study.rl_runs import figure_configs, rl_jobs, train_run
    from softpend.task import Task

    unknown = sorted(set(run_sets) - set(BOOK_RUN_SETS))
    if unknown:
        raise ValueError(f"run sets must be among {list(BOOK_RUN_SETS)}, got {unknown}")
    given = dict(parameters or {})
    seeds, task_overrides = list(given.get("seeds", RL_BOOK.seeds)), given.get("task_overrides") or {}
    rl_seeds = seeds if "rl" in run_sets else seeds[:1] if "first_seed" in run_sets else []
    pilco_seeds = list(given.get("pilco_seeds", PILCO_BOOK.seeds)) if "pilco" in run_sets else []
    if "first_seed" in run_sets and seeds[0] not in pilco_seeds:
        pilco_seeds.insert(0, seeds[0])
    jobs: list[Job] = []
    if pilco_seeds:
        pilco_root = str(given.get("pilco_runs_root", PILCO_BOOK.runs_root))
        config = load_hparams("pilco", apply_overrides(Task(plant=TASK.plant), task_overrides),
                              given.get("pilco_overrides"))
        jobs += [(f"{pilco_root}/{name}", (run_and_save, *args))
                 for name, args in pilco_jobs(config, pilco_seeds, Path(root) / pilco_root)]
    if rl_seeds:
        rl_root = str(given.get("runs_root", RL_BOOK.runs_root))
        configs = figure_configs(task_overrides=task_overrides, rl_overrides=given.get("rl_overrides"))
        specs = [(algo, configs[algo], rl_seeds, given.get(f"episodes_{algo}", getattr(RL_BOOK, f"episodes_{algo}")))
                 for algo in ("dqn", "mbpo")]
        jobs += [(f"{rl_root}/{name}", (train_run, *args)) for name, args in rl_jobs(specs, Path(root) / rl_root)]
    return _order(jobs)


def book_jobs(root: Path | str = ".", profile: str = "full") -> list[Job]:
    """The training runs still missing that the book's notebooks read under ``profile``: for every toc notebook
    with ``softpend: {book_runs: [...]}``, :func:`book_run_jobs` with its profile parameters; a folder two
    notebooks name is trained once, with the settings of the first in toc order."""
    from softpend.study.book import BookLayout, front_matter, load_profiles, read_notebook, toc_notebooks

    layout = BookLayout.at(root)
    toc, profiles = toc_notebooks(layout.toc_path), load_profiles(layout.profiles_path)
    if profile not in profiles:
        raise ValueError(f"unknown profile {profile!r}; {layout.profiles_path} defines {sorted(profiles)}")
    jobs: dict[str, tuple[Any, ...]] = {}
    for name in toc:
        run_sets = front_matter(read_notebook(layout.source_path(name)), name, toc)["book_runs"]
        for job, args in book_run_jobs(run_sets, layout.root, profiles[profile].get(name)) if run_sets else []:
            jobs.setdefault(job, args)
    return _order(list(jobs.items()))


def train_book(root: Path | str = ".", profile: str = "full", workers: Optional[int] = None, progress: bool = True,
               backend: Optional[str] = None) -> dict[str, Any]:
    """Train :func:`book_jobs` in one pool and record what was trained, in how long, in
    ``book/_generated/training.json`` (the execution page shows it); returns that record."""
    import datetime
    import time

    from softpend.io.outputs import atomic_write, json_text
    from softpend.study.book import BookLayout

    jobs, start = book_jobs(root, profile), time.perf_counter()
    workers = default_workers() if workers is None else workers
    _train(jobs, workers, progress, backend)
    record = {"profile": profile, "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
              "trained": [name for name, _ in jobs], "seconds": time.perf_counter() - start, "workers": workers}
    layout = BookLayout.at(root)
    layout.generated_dir.mkdir(parents=True, exist_ok=True)
    with atomic_write(layout.training_path, "w") as handle:
        handle.write(json_text(record, indent=2) + "\n")
    return record

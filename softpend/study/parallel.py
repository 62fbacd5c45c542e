"""Independent training runs on several CPU cores, one process per run.

The book's figures rest on several independent runs (methods x seeds) that each use one core (torch is held to
one thread).  :func:`run_in_processes` runs such jobs in a pool of ``spawn``-started worker processes, so that a
2-core machine trains two runs at a time.  Every job writes its own results to its own folder; the workers
return nothing, and the caller reads the results back from disk, so nothing is lost when one job fails and no
result crosses a process boundary as a pickle.

Workers are started with ``spawn``, which imports the caller's main module again in each worker: a script
that trains in parallel must keep its top-level code under ``if __name__ == "__main__":`` (notebooks, the
``softpend`` command and ``python -c`` need nothing), or set ``SOFTPEND_WORKERS=1``.

A job's numbers do not depend on where it runs: each run seeds everything it draws from its own seed, and a
test checks that a run trained in a worker equals the same run trained in the calling process.
"""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import FIRST_EXCEPTION, Future, ProcessPoolExecutor, wait
from typing import Any, Callable, Optional, Sequence

__all__ = ["default_workers", "run_in_processes"]

#: Environment variable that caps the number of worker processes (``1`` runs every job in the caller).
WORKERS_ENV = "SOFTPEND_WORKERS"


def default_workers() -> int:
    """Worker processes to use: ``$SOFTPEND_WORKERS`` if set, else the CPU cores this process may use."""
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


def _init_worker() -> None:
    import torch

    torch.set_num_threads(1)


def run_in_processes(
    job: Callable[..., None],
    jobs: Sequence[tuple[Any, ...]],
    names: Sequence[str],
    workers: Optional[int] = None,
    progress: bool = True,
    desc: str = "runs",
) -> None:
    """Call ``job(*args)`` for every ``args`` in ``jobs``, in up to ``workers`` processes at once.

    Parameters
    ----------
    job : callable
        A module-level function (it is imported by name in the workers) that writes its results to disk.  It
        is called as ``job(*args, progress=...)``: with this function's ``progress`` in this process, with
        ``False`` in a worker (several bars from several processes would garble the terminal).
    jobs : sequence of tuples
        The arguments of each call, in the order to start them (put the longest first).
    names : sequence of str
        One name per job, used in the progress bar and in errors.
    workers : int, optional
        Processes to use; default :func:`default_workers`.  With 1 (or a single job) the calls run one after
        another in this process, with whatever progress output ``job`` itself prints.
    progress : bool
        Show a bar over finished jobs (only when jobs run in worker processes).
    desc : str
        Label of the progress bar.

    Raises
    ------
    RuntimeError
        Naming the job, if a job raised; the jobs still running are finished first (their results are kept)
        and the jobs not yet started are cancelled.
    """
    if len(jobs) != len(names):
        raise ValueError(f"got {len(jobs)} jobs but {len(names)} names")
    workers = default_workers() if workers is None else int(workers)
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    workers = min(workers, len(jobs))
    if workers <= 1:
        for args in jobs:
            job(*args, progress=progress)
        return

    from tqdm.auto import tqdm

    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_init_worker) as pool:
        futures: dict[Future, str] = {pool.submit(job, *args, progress=False): name for args, name in zip(jobs, names)}
        with tqdm(total=len(futures), desc=desc, unit="run", disable=not progress) as bar:
            pending = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_EXCEPTION)
                for future in done:
                    error = future.exception()
                    if error is not None:
                        for other in pending:
                            other.cancel()
                        wait(pending)
                        raise RuntimeError(f"{desc}: job {futures[future]!r} failed: {error!r}") from error
                    bar.set_postfix_str(futures[future])
                    bar.update(1)

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

Every method's runs share one pool (:mod:`softpend.study.run_pool`), which also trains the runs the book's
notebooks read (``softpend sweep --book``).

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
from typing import Any, Callable, Iterator, Optional, Sequence

__all__ = ["BACKENDS", "SweepFailed", "call_job", "check_backend", "default_backend", "default_workers", "run_jobs"]

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


def _guarded(
    job: Callable[..., None], args: tuple[Any, ...], name: str, progress: bool, one_thread: bool = True
) -> tuple[str, Optional[str]]:
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


def check_backend(backend: str) -> str:
    """``backend`` if it is one of :data:`BACKENDS` and its package is installed; ``ValueError`` naming what is
    missing otherwise (checked before any run, whatever the number of jobs: an engine asked for is never
    silently replaced by running in-process)."""
    import importlib.util

    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {list(BACKENDS)}, got {backend!r}")
    needs = {"ray": ("ray", "ray[default]"), "dask": ("distributed", "dask[distributed]")}.get(backend)
    if needs is not None and importlib.util.find_spec(needs[0]) is None:
        what = "the ray package" if backend == "ray" else "dask.distributed"
        raise ValueError(f"backend {backend!r} needs {what} (pip install '{needs[1]}')")
    return backend


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
    backend = check_backend(default_backend() if backend is None else backend)
    workers = min(int(workers), max(1, len(jobs)))
    pending = dict(zip(names, jobs))
    failures: dict[str, str] = {}
    for attempt in range(int(retries) + 1):
        raised, lost = _run_round(
            job, pending, workers, progress, desc + (f" (retry {attempt})" if attempt else ""), backend
        )
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


def _run_round(
    job: Callable[..., None], pending: dict[str, tuple[Any, ...]], workers: int, progress: bool, desc: str, backend: str
) -> tuple[dict[str, str], set[str]]:
    """One pass over ``pending``: ``(name -> traceback of the jobs that raised, names of the jobs whose worker
    died)``."""
    if workers <= 1:
        raised: dict[str, str] = {}
        for name, args in pending.items():
            _, error = _guarded(job, args, name, progress, one_thread=False)
            if error is not None:
                raised[name] = error
        return raised, set()

    import joblib
    from tqdm.auto import tqdm

    finished: set[str] = set()
    raised = {}
    try:
        # loky's check after a job takes a worker's growth past 300 MB (PILCO's) for a leak and starts a fresh
        # worker for the next job (no job is lost): no warning for that
        warnings.filterwarnings(
            "ignore",
            message="A worker stopped while some jobs were given to the executor",
            category=UserWarning,
            module="joblib",
        )
        with _engine(backend):
            parallel = joblib.Parallel(
                n_jobs=min(workers, len(pending)),
                return_as="generator_unordered",
                **({"backend": "loky"} if backend == "loky" else {}),
            )
            calls = (joblib.delayed(_guarded)(job, args, name, False, True) for name, args in pending.items())
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

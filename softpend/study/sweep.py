"""Independent jobs that write their results to disk, on joblib's ``loky`` pool, Ray or Dask (``$SOFTPEND_BACKEND``)
with ``$SOFTPEND_WORKERS`` workers: a job that raises is reported by name, one whose worker dies is retried."""

from __future__ import annotations

import contextlib
import os
import traceback
import warnings
from typing import Any, Callable, Optional, Sequence

from softpend.checks import int_at_least, one_of

WORKERS_ENV = "SOFTPEND_WORKERS"
BACKEND_ENV = "SOFTPEND_BACKEND"
BACKENDS = ("loky", "ray", "dask")
#: The error of a job whose worker process died (after every retry).
LOST = "its worker process died (killed, out of memory or crashed)"


class SweepFailed(RuntimeError):
    """Jobs that failed after every retry; ``failures``: job name -> last error."""

    def __init__(self, desc: str, failures: dict[str, str]) -> None:
        names = ", ".join(repr(n) for n in failures)
        last = next(iter(failures.values())).strip().splitlines()[-1] if failures else ""
        super().__init__(f"{desc}: job(s) {names} failed ({last})")
        self.failures = failures


def default_workers() -> int:
    """``$SOFTPEND_WORKERS`` if set, else the CPU cores this process may use."""
    if (value := os.environ.get(WORKERS_ENV)) is None:
        return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))
    with contextlib.suppress(ValueError):
        if (workers := int(value)) >= 1:
            return workers
    raise ValueError(f"{WORKERS_ENV} must be a positive integer, got {value!r}")


def default_backend() -> str:
    """``$SOFTPEND_BACKEND`` if set, else ``"loky"``."""
    return one_of(BACKEND_ENV, os.environ.get(BACKEND_ENV, "loky"), BACKENDS)


def _guarded(
    job: Callable[..., None], args: tuple[Any, ...], name: str, progress: bool, one_thread: bool = True
) -> tuple[str, Optional[str]]:
    """Run one job: ``(name, None)`` on success, ``(name, traceback)`` if it raised."""
    if one_thread:
        import torch

        torch.set_num_threads(1)
    try:
        job(*args, progress=progress)
    except Exception:  # noqa: BLE001 -- reported by name to the caller, which retries or raises
        return name, traceback.format_exc()
    return name, None


def check_backend(backend: str) -> str:
    """``backend`` if it is known and its package is installed, else ``ValueError`` (checked before any run)."""
    import importlib.util

    one_of("backend", backend, BACKENDS)
    needs = {"ray": ("ray", "ray[default]"), "dask": ("distributed", "dask[distributed]")}.get(backend)
    if needs is not None and importlib.util.find_spec(needs[0]) is None:
        what = "the ray package" if backend == "ray" else "dask.distributed"
        raise ValueError(f"backend {backend!r} needs {what} (pip install '{needs[1]}')")
    return backend


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
    """Call the module-level ``job(*args, progress=...)`` for every ``args`` of ``jobs`` (named by ``names``),
    ``workers`` at a time (1: in this process), retrying ``retries`` times a job whose worker died; then
    :class:`SweepFailed` names the jobs that failed."""
    workers = int_at_least("workers", default_workers() if workers is None else workers, 1)
    backend = check_backend(default_backend() if backend is None else backend)
    workers, pending, failures = min(workers, max(1, len(jobs))), dict(zip(names, jobs, strict=True)), dict[str, str]()
    for attempt in range(retries + 1):
        retry = f" (retry {attempt})" if attempt else ""
        raised, lost = _run_round(job, pending, workers, progress, desc + retry, backend)
        failures.update(raised)
        pending = {name: pending[name] for name in lost}
        if not pending:
            break
    failures.update({name: LOST for name in pending})
    if failures:
        raise SweepFailed(desc, failures)


def call_job(job: Callable[..., None], *args: Any, progress: bool = True) -> None:
    """The job function of a pool whose jobs call different functions (each ``args`` starts with its own)."""
    job(*args, progress=progress)


def _run_round(
    job: Callable[..., None], pending: dict[str, tuple[Any, ...]], workers: int, progress: bool, desc: str, backend: str
) -> tuple[dict[str, str], set[str]]:
    """One pass over ``pending``: ``({name: traceback} of the jobs that raised, names of the lost jobs)``."""
    if workers <= 1:
        results = [_guarded(job, args, name, progress, one_thread=False) for name, args in pending.items()]
        return {name: error for name, error in results if error is not None}, set()
    import joblib
    from tqdm.auto import tqdm

    finished: dict[str, Optional[str]] = {}
    # loky replaces a worker that grew past its memory check; no job is lost
    message = "A worker stopped while some jobs were given to the executor"
    warnings.filterwarnings("ignore", message=message, category=UserWarning, module="joblib")
    try:
        with contextlib.ExitStack() as stack:  # backend: joblib's active backend, Ray's or Dask's registered first
            if backend == "ray":
                from ray.util.joblib import register_ray

                register_ray()
            elif backend == "dask":
                from dask.distributed import Client

                address = os.environ.get("DASK_SCHEDULER_ADDRESS")
                stack.enter_context(Client(address) if address else Client(processes=True))
            stack.enter_context(joblib.parallel_config(backend=backend))
            parallel = joblib.Parallel(n_jobs=min(workers, len(pending)), return_as="generator_unordered")
            calls = (joblib.delayed(_guarded)(job, args, name, False, True) for name, args in pending.items())
            with tqdm(total=len(pending), desc=desc, unit="run", disable=not progress) as bar:
                for name, error in parallel(calls):
                    finished[name] = error
                    bar.set_postfix_str(name)
                    bar.update(1)
    except ValueError:
        raise
    except Exception:  # noqa: BLE001 -- a worker died (loky's TerminatedWorkerError, a lost Ray/Dask task)
        pass
    raised = {name: error for name, error in finished.items() if error is not None}
    return raised, {name for name in pending if name not in finished}

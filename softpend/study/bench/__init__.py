"""Benchmarks: ``softpend bench`` merges the figures (``dict[str, float]``) of the groups of :data:`BENCHMARKS`."""

from __future__ import annotations

import importlib
import sys
import time
from typing import Any, Callable, Iterable

#: The groups in the order they run; ``group:module`` where ``bench_<group>`` is not in a module of the group's name.
GROUPS = (
    "plant control beam:plant rl:learning pilco:learning pilco_search:learning hardware:control rig_control:control "
    "sysid data_efficiency:control commission:control"
).split()
BENCHMARKS = {g: f"softpend.study.bench.{m or g}:bench_{g}" for g, _, m in (group.partition(":") for group in GROUPS)}


def run_benchmarks(only: Iterable[str] | None = None, progress: bool = True) -> dict[str, float]:
    """Run the selected benchmark groups (default: all) and return all their figures in one dict."""
    selected = list(only) if only else list(BENCHMARKS)
    if unknown := [name for name in selected if name not in BENCHMARKS]:
        raise ValueError(f"unknown benchmark group(s) {unknown}; known: {sorted(BENCHMARKS)}")
    say = (lambda text: print(f"[bench] {text}", file=sys.stderr, flush=True)) if progress else (lambda text: None)
    results: dict[str, float] = {}
    for name in (name for name in BENCHMARKS if name in selected):
        start = time.perf_counter()
        say(f"{name} ...")
        module, function = BENCHMARKS[name].split(":")
        results.update(getattr(importlib.import_module(module), function)())
        say(f"{name} done in {time.perf_counter() - start:.1f} s")
    return results


def best_times(run: Callable[[], Any], repeats: int) -> tuple[float, float]:
    """Shortest wall-clock and CPU seconds of ``repeats`` calls of ``run``."""
    best = best_cpu = float("inf")
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        run()
        best = min(best, time.perf_counter() - start)
        best_cpu = min(best_cpu, time.process_time() - start_cpu)
    return best, best_cpu

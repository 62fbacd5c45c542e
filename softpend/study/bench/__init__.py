"""Benchmarks: ``softpend bench`` runs the groups of :data:`BENCHMARKS` (``"module:function"``, each returning
``dict[str, float]``) and merges their figures."""

from __future__ import annotations

import importlib
import time
from typing import Callable, Iterable

BENCHMARKS: list[tuple[str, str]] = [
    ("plant", "softpend.study.bench.plant:bench_plant"),
    ("control", "softpend.study.bench.control:bench_control"),
    ("beam", "softpend.study.bench.beam:bench_beam"),
    ("rl", "softpend.study.bench.rl:bench_rl"),
    ("pilco", "softpend.study.bench.pilco:bench_pilco"),
    ("pilco_search", "softpend.study.bench.pilco:bench_pilco_search"),
    ("hardware", "softpend.study.bench.hardware:bench_hardware"),
    ("rig_control", "softpend.study.bench.rig_control:bench_rig_control"),
    ("sysid", "softpend.study.bench.sysid:bench_sysid"),
    ("data_efficiency", "softpend.study.bench.data_efficiency:bench_data_efficiency"),
    ("commission", "softpend.study.bench.commission:bench_commission"),
]


def resolve(target: str) -> Callable[[], dict[str, float]]:
    module_name, function_name = target.split(":")
    return getattr(importlib.import_module(module_name), function_name)


def run_benchmarks(only: Iterable[str] | None = None, progress: bool = True) -> dict[str, float]:
    """Run the selected benchmark groups and return all their figures in one dict."""
    selected = list(only) if only else [name for name, _ in BENCHMARKS]
    known = {name for name, _ in BENCHMARKS}
    unknown = [name for name in selected if name not in known]
    if unknown:
        raise ValueError(f"unknown benchmark group(s) {unknown}; known: {sorted(known)}")
    results: dict[str, float] = {}
    for name, target in BENCHMARKS:
        if name not in selected:
            continue
        start = time.perf_counter()
        if progress:
            import sys

            print(f"[bench] {name} ...", file=sys.stderr, flush=True)
        results.update(resolve(target)())
        if progress:
            print(f"[bench] {name} done in {time.perf_counter() - start:.1f} s", file=sys.stderr, flush=True)
    return results

"""``softpend bench``: print measured performance figures."""

from __future__ import annotations

import argparse

from softpend.commands.options import add_command


def register(subparsers: argparse._SubParsersAction) -> None:
    from softpend.study.bench import BENCHMARKS

    only = f"run only this group (repeatable): {list(BENCHMARKS)}"
    options = [("--json", None, dict(action="store_true", help="print one JSON object (default: a table)"))]
    options += [("--only", None, dict(action="append", metavar="GROUP", help=only))]
    add_command(subparsers, "bench", "measure performance figures (see softpend.study.bench)", options, run)


def run(args: argparse.Namespace) -> int:
    from softpend.io.outputs import json_text
    from softpend.study.bench import run_benchmarks

    results = run_benchmarks(args.only)
    if args.json:
        print(json_text(results, indent=2, sort_keys=True))
        return 0
    width = max(map(len, results), default=0)
    for key, value in results.items():
        print(f"{key:<{width}}  {f'{value:.6g}' if isinstance(value, float) else value}")
    return 0

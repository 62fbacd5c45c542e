"""``softpend bench``: print measured performance figures."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    from softpend.study.bench import BENCHMARKS

    parser = subparsers.add_parser("bench", help="measure performance figures (see softpend.study.bench)")
    parser.add_argument("--json", action="store_true", help="print one JSON object (default: a table)")
    parser.add_argument(
        "--only", action="append", metavar="GROUP", help=f"run only this group (repeatable): {list(BENCHMARKS)}"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from softpend.io.outputs import json_text
    from softpend.study.bench import run_benchmarks

    results = run_benchmarks(args.only)
    if args.json:
        print(json_text(results, indent=2, sort_keys=True))
    else:
        width = max(map(len, results), default=0)
        for key, value in results.items():
            print(f"{key:<{width}}  {f'{value:.6g}' if isinstance(value, float) else value}")
    return 0

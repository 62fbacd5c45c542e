"""``softpend book``: execute the book's notebooks (papermill) and optionally build the HTML book."""

from __future__ import annotations

import argparse
import sys

from softpend.commands.options import add_set_option


def register(subparsers: argparse._SubParsersAction) -> None:
    from softpend.study.book import DEFAULT_PROFILE

    parser = subparsers.add_parser(
        "book",
        help="execute the book's notebooks into book/_generated (and build the HTML with --html)",
        description=(
            "Execute the notebooks listed in _toc.yml (toc order, two at a time) with the parameters of a profile "
            "in book/profiles.yml and write book/_generated/NAME.ipynb; up-to-date notebooks are skipped "
            "(execution cache) unless --force. The training runs the notebooks read are trained beforehand by "
            "`softpend sweep --book --profile PROFILE` (a notebook trains what is still missing itself)."
        ),
    )
    parser.add_argument(
        "--profile", default=DEFAULT_PROFILE, help=f"parameter profile (default: {DEFAULT_PROFILE}; 'quick' for tests)"
    )
    parser.add_argument(
        "--only", action="append", metavar="NAME", help="execute only this notebook (repeatable), e.g. fig01_prb_rod"
    )
    add_set_option(
        parser,
        dest="set",
        help="set a parameter (VALUE parsed as JSON, else kept as a string) in every notebook that defines it, "
        "on top of the profile; repeatable. Example: --set plant=beam regenerates the figure set on the "
        "continuum beam",
    )
    parser.add_argument("--force", action="store_true", help="execute even if the cached output is up to date")
    parser.add_argument(
        "--html", action="store_true", help="then build the HTML book (jupyter-book, warnings as errors)"
    )
    parser.add_argument("--root", default=".", help="project root holding _toc.yml (default: current directory)")
    parser.add_argument(
        "--path-output",
        default=None,
        help="with --html: write the HTML to PATH/_build/html (default: ROOT/_build/html)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from softpend.study.book import NotebookExecutionError, build_html, run_notebooks

    try:
        overrides = dict(args.set)
        runs = run_notebooks(args.root, profile=args.profile, only=args.only, force=args.force, overrides=overrides)
    except NotebookExecutionError as exc:
        print(f"softpend book: error: {exc}", file=sys.stderr)
        return 1
    executed = sum(run.status == "executed" for run in runs)
    print(
        f"[book] profile {args.profile!r}: {executed} notebook(s) executed, {len(runs) - executed} up to date",
        file=sys.stderr,
    )
    if args.html:
        try:
            html_dir = build_html(args.root, args.path_output)
        except RuntimeError as exc:
            print(f"softpend book: error: {exc}", file=sys.stderr)
            return 1
        print(f"[book] HTML: {html_dir / 'index.html'}", file=sys.stderr)
    return 0

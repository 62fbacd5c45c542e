"""``softpend book``: execute the book's notebooks (papermill) and optionally build the HTML book."""

from __future__ import annotations

import argparse
import sys

from softpend.commands.options import add_command, set_option

DESCRIPTION = """Execute the notebooks of _toc.yml with a profile of book/profiles.yml into book/_generated/NAME.ipynb,
skipping up-to-date ones unless --force (`softpend sweep --book` trains the runs they read beforehand)."""
SET_HELP = "set a parameter (VALUE as JSON, else text) in each notebook that defines it (repeatable; e.g. plant=beam)"


def register(subparsers: argparse._SubParsersAction) -> None:
    from softpend.study.book import DEFAULT_PROFILE

    options = [
        ("--profile", None, dict(default=DEFAULT_PROFILE, help=f"profile ({DEFAULT_PROFILE}; 'quick' for tests)")),
        ("--only", None, dict(action="append", metavar="NAME", help="execute only this notebook (repeatable)")),
        set_option(SET_HELP, dest="set"),
        ("--force", None, dict(action="store_true", help="execute even if the cached output is up to date")),
        ("--html", None, dict(action="store_true", help="then build the HTML book (jupyter-book, warnings as errors)")),
        ("--root", None, dict(default=".", help="project root holding _toc.yml (default: current directory)")),
        ("--path-output", None, dict(help="with --html: write the HTML to PATH/_build/html (default: ROOT)")),
    ]
    help = "execute the book's notebooks into book/_generated (and build the HTML with --html)"
    add_command(subparsers, "book", help, options, run, description=DESCRIPTION)


def run(args: argparse.Namespace) -> int:
    from softpend.study.book import build_html, run_notebooks

    try:  # a failing notebook (NotebookExecutionError) or jupyter-book build: one line, exit status 1
        runs = run_notebooks(args.root, args.profile, args.only, args.force, overrides=dict(args.set))
        executed = sum(run.status == "executed" for run in runs)
        summary = f"{executed} notebook(s) executed, {len(runs) - executed} up to date"
        print(f"[book] profile {args.profile!r}: {summary}", file=sys.stderr)
        if args.html:
            print(f"[book] HTML: {build_html(args.root, args.path_output) / 'index.html'}", file=sys.stderr)
    except RuntimeError as exc:
        print(f"softpend book: error: {exc}", file=sys.stderr)
        return 1
    return 0

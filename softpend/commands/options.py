"""Options shared by the subcommands: the repeatable ``--set NAME=VALUE`` (and its per-method forms)."""

from __future__ import annotations

import argparse
from typing import Any

from softpend.io.overrides import parse_assignment

__all__ = ["add_set_option", "assignment"]


def assignment(text: str) -> tuple[str, Any]:
    """``argparse`` type of ``--set``: :func:`softpend.io.overrides.parse_assignment`, its ``ValueError``
    turned into an ``argparse`` error that shows the message."""
    try:
        return parse_assignment(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_set_option(parser: argparse.ArgumentParser, help: str, dest: str = "overrides", flag: str = "--set") -> None:
    """Add the repeatable ``flag NAME=VALUE`` (``--set`` by default) to ``parser``; ``args.<dest>`` is the list of
    ``(NAME, value)`` pairs in command-line order (VALUE parsed as JSON, else kept as a string)."""
    parser.add_argument(flag, action="append", default=[], type=assignment, metavar="NAME=VALUE", dest=dest, help=help)

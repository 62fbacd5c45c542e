"""Options shared by the subcommands: the repeatable ``--set NAME=VALUE`` (and its per-method forms)."""

from __future__ import annotations

import argparse
from typing import Any

from softpend.io.overrides import parse_assignment


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


#: Longest session of a command that runs a rig, the twin or a camera for a duration [s]: one day.
MAX_SESSION_S = 86_400.0


def check_numbers(args: argparse.Namespace, limits: dict[str, tuple[float, float]]) -> None:
    """Range-check numeric options before any work starts: ``limits`` maps an option's flag (``"--camera-fps"``)
    to the closed interval ``(low, high)`` its value (or each of its values) must lie in; an option left at
    ``None`` passes.  ``ValueError`` naming the flag, the interval and the value (NaN and infinities never
    pass)."""
    from softpend.checks import in_range

    for flag, (low, high) in limits.items():
        value = getattr(args, flag.lstrip("-").replace("-", "_"))
        for item in value if isinstance(value, (list, tuple)) else [value]:
            if item is not None:
                in_range(flag, item, low, high)

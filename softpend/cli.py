"""The ``softpend`` command line.

Each subcommand lives in its own module under :mod:`softpend.commands` and exposes
``register(subparsers)``, which adds an ``argparse`` sub-parser whose ``func`` default runs the command
and returns an exit code.  To add a command, create the module and list it in :data:`COMMAND_MODULES`.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from typing import Sequence

#: Modules that contribute subcommands (one line per module).
COMMAND_MODULES: list[str] = [
    "softpend.commands.bench",
    "softpend.commands.book",
    "softpend.commands.train",
    "softpend.commands.evaluate",
    "softpend.commands.rig",
    "softpend.commands.track",
    "softpend.commands.babble",
    "softpend.commands.fit_model",
]


def build_parser() -> argparse.ArgumentParser:
    from softpend import __version__

    parser = argparse.ArgumentParser(prog="softpend", description="Learning to control a soft robotic pendulum.")
    parser.add_argument("--version", action="version", version=f"softpend {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(subparsers)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as exc:
        print(f"softpend {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"softpend {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

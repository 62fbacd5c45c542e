"""The ``softpend`` command line (a module with ``register(subparsers)`` per subcommand); an input error is one line
``softpend COMMAND: error: ...`` on stderr, exit 2 (``--debug``: the traceback)."""

from __future__ import annotations

import argparse
import importlib
import pickle
import sys
import zipfile
from typing import NoReturn, Sequence

#: Modules of softpend.commands that contribute subcommands.
COMMANDS = "bench book train evaluate rig track babble fit_model identify sweep".split()
DEBUG_HELP = "show the traceback of an error instead of one line"


class CommandParser(argparse.ArgumentParser):
    """``ArgumentParser`` whose usage errors are one line on stderr (``softpend train: error: ...``), exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    from softpend import __version__

    parser = CommandParser(prog="softpend", description="Learning to control a soft robotic pendulum.")
    parser.add_argument("--version", action="version", version=f"softpend {__version__}")
    parser.add_argument("--debug", action="store_true", help=DEBUG_HELP)
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"softpend.commands.{name}").register(subparsers)
    _add_debug(parser)
    return parser


def _add_debug(parser: argparse.ArgumentParser) -> None:
    """Give every subcommand, at any depth, its own ``--debug``."""
    for action in (a for a in parser._actions if isinstance(a, argparse._SubParsersAction)):
        for subparser in action.choices.values():
            subparser.add_argument("--debug", action="store_true", default=argparse.SUPPRESS, help=DEBUG_HELP)
            _add_debug(subparser)


#: Exception types that are the input's or the environment's fault, reported in one line (as are the error classes
#: of softpend itself and of Exudyn).
REPORTED_ERRORS: tuple[type[BaseException], ...] = (ValueError, OSError, EOFError, RecursionError, MemoryError)
REPORTED_ERRORS += (OverflowError, zipfile.BadZipFile, pickle.UnpicklingError)
#: The message of an error of these classes raised without one.
SILENT_ERRORS = ((MemoryError, "not enough memory"), (RecursionError, "input nested too deeply"))


def error_line(exc: BaseException) -> str:
    """``exc``'s message on one line, prefixed by its class name unless it is a plain ``ValueError``."""
    message = " ".join(str(exc).split())
    if type(exc) is ValueError and message:
        return message
    message = message or next((text for kind, text in SILENT_ERRORS if isinstance(exc, kind)), "")
    return f"{type(exc).__name__}: {message}" if message else type(exc).__name__


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a usage error already reported on stderr
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except Exception as exc:
        ours = (type(exc).__module__ or "").split(".")[0] in ("softpend", "exudyn")
        if getattr(args, "debug", False) or not (ours or isinstance(exc, REPORTED_ERRORS)):
            raise
        print(f"softpend {args.command}: error: {error_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"softpend {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

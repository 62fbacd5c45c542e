"""Options shared by the subcommands: option tables with checked number ranges, and the repeatable ``--set``."""

from __future__ import annotations

import argparse
from typing import Any, Callable, Optional, Sequence

from softpend.io.overrides import parse_assignment

#: Longest session of a command that runs a rig, the twin or a camera for a duration [s]: one day.
MAX_SESSION_S = 86_400.0

#: A row of an option table: ``(flag, closed interval its value must lie in or None, add_argument keywords)``.
Option = tuple[str, Optional[tuple[float, float]], dict[str, Any]]


def add_command(
    subparsers: argparse._SubParsersAction, name: str, help: str, options: Sequence[Option], run: Callable, **kw: Any
) -> argparse.ArgumentParser:
    """A subcommand ``name`` with the options of a table (positionals included) that runs ``run(args)``; a value
    outside an option's interval is a usage error naming the flag."""
    parser = subparsers.add_parser(name, help=help, **kw)
    for flag, limits, keywords in options:
        if limits is not None:
            keywords = dict(keywords, type=ranged(keywords["type"], flag, *limits))
        parser.add_argument(flag, **keywords)
    parser.set_defaults(func=run)
    return parser


def add_target(parser: argparse.ArgumentParser, flag: str = "--port") -> None:
    """The required choice between ``--twin`` (the emulator and its synthetic camera) and ``flag`` (a rig's)."""
    target = parser.add_mutually_exclusive_group(required=True)
    target.add_argument("--twin", action="store_true", help="the digital twin (emulator + synthetic camera)")
    text = "serial port of a rig (or the pty of `softpend rig`)" if flag == "--port" else "index, URL or image/video"
    target.add_argument(flag, metavar=flag[2:].upper().replace("PORT", "PATH"), help=text)


def ranged(kind: type, flag: str, low: float, high: float) -> Callable[[str], Any]:
    def parse(text: str) -> Any:
        from softpend.checks import in_range

        value = kind(text)
        try:
            in_range(flag, value, low, high)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        return value

    parse.__name__ = kind.__name__  # argparse's "invalid float value: ..."
    return parse


#: A row of a table of config fields as options: ``(flag, field, type, help, closed interval or None)``.
FieldOption = tuple[str, str, type, str, Optional[tuple[float, float]]]


def field_options(defaults: Any, rows: Sequence[FieldOption]) -> list[Option]:
    """Options that set config fields, each defaulting to (and its help showing) the field of ``defaults``."""
    return [
        (flag, limits, dict(type=kind, default=getattr(defaults, field), help=f"{text} ({getattr(defaults, field)})"))
        for flag, field, kind, text, limits in rows
    ]


def field_values(args: argparse.Namespace, rows: Sequence[FieldOption]) -> dict[str, Any]:
    """``field -> value`` of the options of :func:`field_options`."""
    return {field: getattr(args, flag[2:].replace("-", "_")) for flag, field, *_ in rows}


def assignment(text: str) -> tuple[str, Any]:
    """``argparse`` type of ``--set``: :func:`softpend.io.overrides.parse_assignment` as an ``argparse`` error."""
    try:
        return parse_assignment(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def set_option(help: str, dest: str = "overrides", flag: str = "--set") -> Option:
    """The repeatable ``flag NAME=VALUE``: ``args.<dest>`` lists the ``(NAME, value)`` pairs (VALUE as JSON, else text)."""
    return (flag, None, dict(action="append", default=[], type=assignment, metavar="NAME=VALUE", dest=dest, help=help))


def camera_source(args: argparse.Namespace, tracker: Any = None) -> Any:
    """The tip source of ``--camera`` (``tracker``: a TipTracker), calibrated by ``--calibration`` or ``--markers``."""
    from softpend.vision.calibration import AffineCalibration, read_markers
    from softpend.vision.tip_source import FrameTracker, open_tip_source

    calibration = AffineCalibration.load(args.calibration) if args.calibration else None
    frame_tracker = FrameTracker(tracker, calibration, read_markers("--markers", args.markers))
    return open_tip_source(args.camera, latency_s=args.camera_latency_ms / 1000.0, frame_tracker=frame_tracker)

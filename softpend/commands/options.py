"""Options shared by the subcommands: option tables with checked number ranges, and the repeatable ``--set``."""

from __future__ import annotations

import argparse
from typing import Any, Callable, Optional, Sequence

from softpend.io.overrides import parse_assignment

#: Longest session of a command that runs a rig, the twin or a camera for a duration [s]: one day.
MAX_SESSION_S = 86_400.0

#: A row of an option table: ``(flag, closed interval its value must lie in or None, add_argument keywords)``.
Option = tuple[str, Optional[tuple[float, float]], dict[str, Any]]


def add_options(parser: argparse.ArgumentParser, options: Sequence[Option]) -> None:
    """Add the options of a table to ``parser``; a value outside its interval is a usage error naming the flag."""
    for flag, limits, keywords in options:
        if limits is not None:
            keywords = dict(keywords, type=_ranged(keywords["type"], flag, *limits))
        parser.add_argument(flag, **keywords)


def _ranged(kind: type, flag: str, low: float, high: float) -> Callable[[str], Any]:
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


def add_field_options(parser: argparse.ArgumentParser, defaults: Any, rows: Sequence[FieldOption]) -> None:
    """Add options that set fields of a config, each defaulting to (and its help showing) the field of
    ``defaults``; :func:`field_values` reads them back."""
    keywords = [
        dict(type=kind, default=getattr(defaults, field), help=f"{text} ({getattr(defaults, field)})")
        for _, field, kind, text, _ in rows
    ]
    add_options(parser, [(row[0], row[4], kw) for row, kw in zip(rows, keywords)])


def field_values(args: argparse.Namespace, rows: Sequence[FieldOption]) -> dict[str, Any]:
    """``field -> value`` of the options of :func:`add_field_options`."""
    return {field: getattr(args, flag[2:].replace("-", "_")) for flag, field, *_ in rows}


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


def check_numbers(args: argparse.Namespace, limits: dict[str, tuple[float, float]]) -> None:
    """``ValueError`` naming the flag, the interval and the value unless each option of ``limits`` (flag ->
    ``(low, high)``) is None or lies in its interval (each value of a list; NaN and infinities never pass)."""
    from softpend.checks import in_range

    for flag, (low, high) in limits.items():
        value = getattr(args, flag.lstrip("-").replace("-", "_"))
        for item in value if isinstance(value, (list, tuple)) else [value]:
            if item is not None:
                in_range(flag, item, low, high)


def camera_source(args: argparse.Namespace, tracker: Any = None) -> Any:
    """The tip source of ``--camera`` (tracking with ``tracker``, a TipTracker), calibrated by ``--calibration`` or
    on ``--markers``, with ``--camera-latency-ms``."""
    from softpend.vision.calibration import AffineCalibration, read_markers
    from softpend.vision.tip_source import FrameTracker, open_tip_source

    calibration = AffineCalibration.load(args.calibration) if args.calibration else None
    frame_tracker = FrameTracker(tracker, calibration, read_markers("--markers", args.markers))
    return open_tip_source(args.camera, latency_s=args.camera_latency_ms / 1000.0, frame_tracker=frame_tracker)

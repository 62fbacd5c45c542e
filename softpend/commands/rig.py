"""``softpend rig``: serve the emulated rig on a pseudo-terminal (its path printed on one line) until Ctrl-C, SIGTERM
or ``--duration``; ``softpend rig control`` and the build actions are its sub-commands."""

from __future__ import annotations

import argparse

from softpend.commands.options import MAX_SESSION_S

#: The numeric options: (flag, type, default, closed interval checked before anything starts, help).
NUMBERS = (
    ("--duration", float, None, (1e-3, MAX_SESSION_S), "stop after this many seconds (default: run until killed)"),
    ("--counts-per-rev", int, 4096, (4, 2**24), "encoder resolution (default 4096)"),
    ("--latency-ms", float, 2.0, (0.0, 1000.0), "one-way link latency [ms] (default 2)"),
    ("--drop", float, 0.0, (0.0, 1.0), "probability that a STATE frame is dropped"),
    ("--garble", float, 0.0, (0.0, 1.0), "probability that a STATE frame is corrupted"),
    ("--watchdog-ms", int, 100, (1, 65535), "device watchdog [ms] (default 100)"),
    ("--n-links", int, 4, None, "PRB links of the simulated rod"),
    ("--seed", int, 0, None, "seed for drops, garbling and start noise"),
)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("rig", help="serve the emulated rig (motor protocol) on a pseudo-terminal")
    parser.add_argument("--port", metavar="PATH", help="also expose the pty at PATH (a symlink, like /tmp/ttyRIG)")
    for flag, kind, default, _, text in NUMBERS:
        parser.add_argument(flag, type=kind, default=default, help=text)
    parser.add_argument("--truth-log", metavar="CSV", help="record the true joint state every tick (crash-safe CSV)")
    parser.set_defaults(func=run)
    from softpend.commands import rig_build, rig_commission, rig_control

    actions = parser.add_subparsers(dest="rig_action", metavar="ACTION")
    rig_control.register(actions)
    rig_build.register(actions)
    rig_commission.register(actions)
    debug = dict(
        action="store_true", default=argparse.SUPPRESS, help="show the traceback of an error instead of one line"
    )
    for action in actions.choices.values():
        action.add_argument("--debug", **debug)


def run(args: argparse.Namespace) -> int:
    from softpend.commands.options import check_numbers
    from softpend.hardware.emulator import RigConfig, serve_forever
    from softpend.io.outputs import Outputs
    from softpend.task import Task

    check_numbers(args, {flag: limits for flag, _, _, limits, _ in NUMBERS if limits is not None})
    outputs = Outputs()
    if args.truth_log is not None:  # an empty one is an error, not no log
        outputs.file(args.truth_log, what="--truth-log")
    config = RigConfig(
        task=Task(start_noise_rad=0.0).replace(n_links=args.n_links),
        counts_per_rev=args.counts_per_rev,
        latency_s=args.latency_ms / 1000.0,
        drop_probability=args.drop,
        garble_probability=args.garble,
        watchdog_ms=args.watchdog_ms,
        seed=args.seed,
        duration_s=args.duration,
    )
    if args.truth_log is None:
        return serve_forever(config, link_path=args.port)
    try:
        return serve_forever(config, truth_log=str(outputs.live(args.truth_log)), link_path=args.port)
    finally:
        outputs.done(args.truth_log)

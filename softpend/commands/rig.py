"""``softpend rig``: serve the emulated rig on a pseudo-terminal (path printed) until Ctrl-C, SIGTERM or --duration."""

from __future__ import annotations

import argparse

from softpend.commands.options import MAX_SESSION_S, Option, add_command

OPTIONS: tuple[Option, ...] = (
    ("--port", None, dict(metavar="PATH", help="also expose the pty at PATH (a symlink, like /tmp/ttyRIG)")),
    ("--duration", (1e-3, MAX_SESSION_S), dict(type=float, help="stop after this many seconds (default: never)")),
    ("--counts-per-rev", (4, 2**24), dict(type=int, default=4096, help="encoder resolution (default 4096)")),
    ("--latency-ms", (0.0, 1000.0), dict(type=float, default=2.0, help="one-way link latency [ms] (default 2)")),
    ("--drop", (0.0, 1.0), dict(type=float, default=0.0, help="probability that a STATE frame is dropped")),
    ("--garble", (0.0, 1.0), dict(type=float, default=0.0, help="probability that a STATE frame is corrupted")),
    ("--watchdog-ms", (1, 65535), dict(type=int, default=100, help="device watchdog [ms] (default 100)")),
    ("--n-links", None, dict(type=int, default=4, help="PRB links of the simulated rod")),
    ("--seed", None, dict(type=int, default=0, help="seed for drops, garbling and start noise")),
    ("--truth-log", None, dict(metavar="CSV", help="record the true joint state every tick (crash-safe CSV)")),
)


def register(subparsers: argparse._SubParsersAction) -> None:
    from softpend.commands import rig_build, rig_commission, rig_control

    help = "serve the emulated rig (motor protocol) on a pseudo-terminal"
    actions = add_command(subparsers, "rig", help, OPTIONS, run).add_subparsers(dest="rig_action", metavar="ACTION")
    for module in (rig_control, rig_build, rig_commission):
        module.register(actions)


def run(args: argparse.Namespace) -> int:
    from softpend.hardware.emulator import RigConfig, serve_forever
    from softpend.io.outputs import Outputs
    from softpend.task import Task

    outputs = Outputs()
    if args.truth_log is not None:  # an empty one is an error, not no log
        outputs.file(args.truth_log, what="--truth-log")
    link = dict(counts_per_rev=args.counts_per_rev, latency_s=args.latency_ms / 1000.0, watchdog_ms=args.watchdog_ms)
    faults = dict(drop_probability=args.drop, garble_probability=args.garble, seed=args.seed, duration_s=args.duration)
    config = RigConfig(task=Task(start_noise_rad=0.0).replace(n_links=args.n_links), **link, **faults)
    truth_log = None if args.truth_log is None else str(outputs.live(args.truth_log))
    try:
        return serve_forever(config, truth_log=truth_log, link_path=args.port)
    finally:
        if truth_log is not None:
            outputs.done(args.truth_log)

"""``softpend rig commission``: commission an unknown rod on the digital twin (excite, identify, design, train,
verify, report; :mod:`softpend.study.commission`), each stage's output in ``--out``, a stage already done there
kept."""

from __future__ import annotations

import argparse
import os

from softpend.commands.options import MAX_SESSION_S, Option, add_command, ranged

#: The controller classes (:data:`softpend.study.commission.CLASSES`, named here so the CLI starts without it).
CLASSES = ("swingup", "dqn", "mbpo", "pilco")

#: The :class:`~softpend.study.commission.CommissionConfig` options: field -> (low, high, help with the config's
#: default); a field ending in ``_s`` is a float, the others integers.
CONFIG_OPTIONS: dict[str, tuple[float, float, str]] = {
    "seed": (0, 10**6 - 1, "seed of the commissioning (0)"),
    "excite_s": (1e-3, MAX_SESSION_S, "seconds of excitation (10)"),
    "trial_length_s": (0.1, MAX_SESSION_S, "trial length of the rig dataset [s] (3)"),
    "max_windows": (1, 10**5, "identification windows (60)"),
    "max_iterations": (1, 10**4, "identification iterations (25)"),
    "check_draws": (1, 10**4, "design check: rods drawn from the uncertainty (8)"),
    "check_starts": (1, 10**4, "design check: simulator starts per rod (2)"),
    "check_duration_s": (1e-3, MAX_SESSION_S, "design check: start length [s] (10)"),
    "train_attempts": (1, 100, "training runs per learner at most, until one balances on its own starts (3)"),
    "verify_starts": (1, 1000, "fresh twin starts per condition (10)"),
    "verify_duration_s": (1e-3, MAX_SESSION_S, "length of a twin start [s] (10)"),
}


def register(actions: argparse._SubParsersAction) -> None:
    help = (
        "commission an unknown rod on the twin: excite, identify, design swing-up + LQR, train DQN, DQN-MBPO and "
        "PILCO, verify, report"
    )
    default = "a run folder of LEARNER (dqn, mbpo, pilco) trained for the default rod, verified beside (repeatable)"
    options: list[Option] = [
        ("--out", None, dict(required=True, metavar="DIR", help="folder of the stages' outputs and report.json")),
        *(
            (f"--{name.replace('_', '-')}", (low, high), dict(type=float if name.endswith("_s") else int, help=text))
            for name, (low, high, text) in CONFIG_OPTIONS.items()
        ),
        (
            "--controllers",
            None,
            dict(nargs="+", choices=CLASSES, default=list(CLASSES), help="controller classes (default: all)"),
        ),
        ("--default-run", None, dict(nargs=2, action="append", default=[], metavar=("LEARNER", "DIR"), help=default)),
        ("--json", None, dict(action="store_true", help="print the report as JSON")),
    ]
    parser = add_command(actions, "commission", help, options, run, description=__doc__.split("\n\n")[0])
    rod = parser.add_mutually_exclusive_group(required=True)
    rod.add_argument("--twin-rod", metavar="FILE", help="the twin's rod: a rod JSON (optional torque_gain)")
    seed = ranged(int, "--twin-seed", 0, 2**63 - 1)
    rod.add_argument("--twin-seed", type=seed, metavar="N", help="the twin's rod: an unknown rod drawn from seed N")


def run(args: argparse.Namespace) -> int:
    from softpend.io.outputs import json_text
    from softpend.io.reading import check_regular_file
    from softpend.study.commission import CommissionConfig, commission
    from softpend.study.twin_side import TwinTruth

    truth = TwinTruth(rod_file=args.twin_rod, seed=args.twin_seed)  # an empty path is refused here
    if args.twin_rod is not None:  # its kind only: the file is read on the twin's side, never here
        if not os.path.exists(args.twin_rod):
            raise ValueError(f"--twin-rod {args.twin_rod}: no such file")
        check_regular_file(args.twin_rod, "--twin-rod")
    config = CommissionConfig(
        **{k: getattr(args, k) for k in CONFIG_OPTIONS if getattr(args, k) is not None},
        controllers=tuple(args.controllers),
        default_rod_runs=dict(args.default_run),
    )

    def told(stage: str, ran: bool, output: dict) -> None:
        if not args.json:
            print(f"{stage}: {'done' if ran else 'kept from an earlier run'}", flush=True)

    report = commission(args.out, truth, config, on_stage=told)
    if args.json:
        print(json_text(report, indent=2))
        return 0
    for entry in report["classes"].values():
        for row in entry["verification"] + (entry["default_rod_verification"] or []):
            print(
                f"{row['controller']}, {row['condition']}: {row['successes']} of {row['starts']} balanced "
                f"(95% interval {row['success_low']:.2f} to {row['success_high']:.2f})"
            )
        print(
            f"{entry['label']}: {entry['plant_s']:.1f} plant seconds (excitation and verification), "
            f"{entry['simulator_s']:.1f} simulator seconds (design check or training)"
        )
    print(f"report in {args.out}")
    return 0

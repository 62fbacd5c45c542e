"""``softpend rig commission``: commission an unknown rod on the digital twin (excite, identify, design, verify,
report; :mod:`softpend.study.commission`), each stage's output in ``--out``, a stage already done there kept."""

from __future__ import annotations

import argparse
import os

from softpend.commands.options import MAX_SESSION_S, check_numbers

#: The closed interval of each numeric option, checked before anything starts.
OPTION_RANGES: dict[str, tuple[float, float]] = {
    "--twin-seed": (0, 2**63 - 1),
    "--seed": (0, 10**6 - 1),
    "--excite-s": (1e-3, MAX_SESSION_S),
    "--trial-length-s": (0.1, MAX_SESSION_S),
    "--max-windows": (1, 10**5),
    "--max-iterations": (1, 10**4),
    "--check-draws": (1, 10**4),
    "--check-starts": (1, 10**4),
    "--check-duration-s": (1e-3, MAX_SESSION_S),
    "--verify-starts": (1, 1000),
    "--verify-duration-s": (1e-3, MAX_SESSION_S),
}


def register(actions: argparse._SubParsersAction) -> None:
    parser = actions.add_parser(
        "commission",
        help="commission an unknown rod on the twin: excite, identify, design swing-up + LQR, verify, report",
        description=__doc__.split("\n\n")[0],
    )
    rod = parser.add_mutually_exclusive_group(required=True)
    rod.add_argument("--twin-rod", metavar="FILE", help="the twin's rod: a rod JSON (optional torque_gain)")
    rod.add_argument("--twin-seed", type=int, metavar="N", help="the twin's rod: an unknown rod drawn from seed N")
    parser.add_argument("--out", required=True, metavar="DIR", help="folder of the stages' outputs and report.json")
    parser.add_argument("--seed", type=int, default=0, help="seed of the commissioning (0)")
    parser.add_argument("--excite-s", type=float, default=20.0, help="seconds of multisine excitation (20)")
    parser.add_argument("--trial-length-s", type=float, default=3.0, help="trial length of the rig dataset [s] (3)")
    parser.add_argument("--max-windows", type=int, default=60, help="identification windows (60)")
    parser.add_argument("--max-iterations", type=int, default=25, help="identification iterations (25)")
    parser.add_argument("--check-draws", type=int, default=8, help="design check: rods drawn from the uncertainty (8)")
    parser.add_argument("--check-starts", type=int, default=2, help="design check: simulator starts per rod (2)")
    parser.add_argument("--check-duration-s", type=float, default=10.0, help="design check: start length [s] (10)")
    parser.add_argument("--verify-starts", type=int, default=10, help="fresh twin starts per condition (10)")
    parser.add_argument("--verify-duration-s", type=float, default=10.0, help="length of a twin start [s] (10)")
    parser.add_argument("--json", action="store_true", help="print the report as JSON")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from softpend.io.outputs import json_text
    from softpend.io.reading import check_regular_file
    from softpend.study.commission import CommissionConfig, commission
    from softpend.study.twin_side import TwinTruth

    check_numbers(args, OPTION_RANGES)
    if args.twin_rod is not None:
        if not args.twin_rod.strip():
            raise ValueError("--twin-rod: the path is empty")
        # its kind only: the file is read on the twin's side, never here
        if not os.path.exists(args.twin_rod):
            raise ValueError(f"--twin-rod {args.twin_rod}: no such file")
        check_regular_file(args.twin_rod, "--twin-rod")
    truth = TwinTruth(rod_file=args.twin_rod, seed=args.twin_seed)
    config = CommissionConfig(
        excite_s=args.excite_s,
        trial_length_s=args.trial_length_s,
        max_windows=args.max_windows,
        max_iterations=args.max_iterations,
        check_draws=args.check_draws,
        check_starts=args.check_starts,
        check_duration_s=args.check_duration_s,
        verify_starts=args.verify_starts,
        verify_duration_s=args.verify_duration_s,
        seed=args.seed,
    )

    def told(stage: str, ran: bool, output: dict) -> None:
        if not args.json:
            print(f"{stage}: {'done' if ran else 'kept from an earlier run'}", flush=True)

    report = commission(args.out, truth, config, on_stage=told)
    if args.json:
        print(json_text(report, indent=2))
        return 0
    for row in report["verification"]:
        print(
            f"{row['condition']}: {row['successes']} of {row['starts']} balanced "
            f"(95% interval {row['success_low']:.2f} to {row['success_high']:.2f})"
        )
    print(f"plant seconds of the commissioning: {report['plant_s']['commissioning']:.1f}; report in {args.out}")
    return 0

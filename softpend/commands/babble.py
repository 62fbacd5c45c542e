"""``softpend babble``: record a motor-babbling dataset from the simulator."""

from __future__ import annotations

import argparse
import math
import time

from softpend.commands.options import check_numbers

#: Plausible ranges of the babbling options (a wider value gives a dataset of noise, or of saturated torques,
#: that still passes as data): noise stds up to a half turn or a metre, gains and the random torque's std far
#: beyond the defaults.
BABBLE_RANGES: dict[str, tuple[float, float]] = {
    "--phi-noise-std-rad": (0.0, math.pi),
    "--er-noise-std-rad": (0.0, math.pi),
    "--tip-noise-std-m": (0.0, 1.0),
    "--feedback-kp": (0.0, 1e4),
    "--feedback-kd": (0.0, 1e3),
    "--torque-std-fraction": (0.0, 100.0),
    "--torque-bandwidth-hz": (1e-3, 1e4),
    "--camera-delay-steps": (0, 10**6),
    "--multisine-peak-fraction": (0.0, 1.0),
}


def register(subparsers: argparse._SubParsersAction) -> None:
    from softpend.sysid import BabbleProtocol

    d = BabbleProtocol()
    parser = subparsers.add_parser(
        "babble",
        help="record a motor-babbling dataset (random torques near upright) for system identification",
        description="Drive the simulated soft rod with band-limited random torques (plus a weak stabilising PD "
        "on the hub in most trials) and save positions, differenced velocities and torques as a dataset "
        "file (softpend.sysid.dataset format).",
    )
    parser.add_argument("output", help="dataset file to write (.npz)")
    parser.add_argument("--seed", type=int, default=0, help="seed of every random draw (default 0)")
    parser.add_argument("--n-trials", type=int, default=d.n_trials, help=f"number of trials ({d.n_trials})")
    parser.add_argument(
        "--trial-length-s", type=float, default=d.trial_length_s, help=f"trial length [s] ({d.trial_length_s})"
    )
    parser.add_argument("--dt-s", type=float, default=d.dt_s, help=f"sampling step [s] ({d.dt_s})")
    parser.add_argument(
        "--start", choices=("upright", "hanging", "random"), default=d.start, help=f"start region ({d.start})"
    )
    parser.add_argument(
        "--program",
        choices=("noise", "multisine"),
        default=d.program,
        help="torque program: band-limited random torque, or a designed multisine from 0.2 Hz to "
        f"--torque-bandwidth-hz ({d.program})",
    )
    parser.add_argument(
        "--multisine-peak-fraction",
        type=float,
        default=d.multisine_peak_fraction,
        help=f"peak of the multisine / torque limit ({d.multisine_peak_fraction})",
    )
    parser.add_argument(
        "--torque-std-fraction", type=float, default=d.torque_std_fraction, help="random torque std / torque limit"
    )
    parser.add_argument(
        "--torque-bandwidth-hz",
        type=float,
        default=d.torque_bandwidth_hz,
        help="low-pass cut-off of the random torque, upper band edge of the multisine [Hz]",
    )
    parser.add_argument(
        "--feedback-trial-fraction",
        type=float,
        default=d.feedback_trial_fraction,
        help="fraction of trials with the stabilising PD",
    )
    parser.add_argument(
        "--feedback-kp", type=float, default=d.feedback_kp_nm_per_rad, help="PD gain on the hub angle [N m/rad]"
    )
    parser.add_argument(
        "--feedback-kd", type=float, default=d.feedback_kd_nms_per_rad, help="PD gain on the hub rate [N m s/rad]"
    )
    parser.add_argument("--phi-noise-std-rad", type=float, default=0.0, help="encoder noise std [rad]")
    parser.add_argument("--tip-noise-std-m", type=float, default=0.0, help="camera tip-position noise std [m]")
    parser.add_argument("--er-noise-std-rad", type=float, default=0.0, help="tip-rotation noise std [rad]")
    parser.add_argument("--camera-delay-steps", type=int, default=0, help="camera delay [samples]")
    parser.add_argument("--n-links", type=int, default=None, help="override the number of PRB links")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from softpend.io.outputs import Outputs, json_text, output_name
    from softpend.plant import RodParams
    from softpend.sysid import BabbleProtocol, babble

    check_numbers(args, BABBLE_RANGES)  # before anything starts: a dataset of data, not of noise
    outputs = Outputs()  # before the work: a dataset this command wrote may be replaced, no other file
    output = str(outputs.file(output_name(args.output, ".npz", "dataset"), what="dataset"))

    protocol = BabbleProtocol(
        n_trials=args.n_trials,
        trial_length_s=args.trial_length_s,
        dt_s=args.dt_s,
        start=args.start,
        program=args.program,
        multisine_peak_fraction=args.multisine_peak_fraction,
        torque_std_fraction=args.torque_std_fraction,
        torque_bandwidth_hz=args.torque_bandwidth_hz,
        feedback_trial_fraction=args.feedback_trial_fraction,
        feedback_kp_nm_per_rad=args.feedback_kp,
        feedback_kd_nms_per_rad=args.feedback_kd,
        phi_noise_std_rad=args.phi_noise_std_rad,
        tip_noise_std_m=args.tip_noise_std_m,
        er_noise_std_rad=args.er_noise_std_rad,
        camera_delay_steps=args.camera_delay_steps,
    )
    params = RodParams() if args.n_links is None else RodParams(n_links=args.n_links)
    started = time.perf_counter()
    dataset = babble(protocol, params=params, seed=args.seed, path=output, progress=not args.no_progress)
    outputs.done(output)  # written atomically by the dataset's writer
    elapsed = time.perf_counter() - started
    summary = {
        "path": output,
        "n_trials": dataset.n_trials,
        "n_samples": dataset.n_samples,
        "n_transitions": dataset.n_transitions,
        "wall_s": round(elapsed, 2),
    }
    print(json_text(summary))
    return 0

"""``softpend babble``: record a motor-babbling dataset from the simulator."""

from __future__ import annotations

import argparse
import math
import time

from softpend.commands.options import FieldOption, Option, add_command, field_options, field_values

#: ``(flag, BabbleProtocol field, type, help, allowed range)`` of the protocol options.
_OPTIONS: tuple[FieldOption, ...] = (
    ("--n-trials", "n_trials", int, "number of trials", None),
    ("--trial-length-s", "trial_length_s", float, "trial length [s]", None),
    ("--dt-s", "dt_s", float, "sampling step [s]", None),
    ("--multisine-peak-fraction", "multisine_peak_fraction", float, "peak of the multisine / torque limit", (0.0, 1.0)),
    ("--torque-std-fraction", "torque_std_fraction", float, "random torque std / torque limit", (0.0, 100.0)),
    ("--torque-bandwidth-hz", "torque_bandwidth_hz", float, "random torque cut-off, multisine top [Hz]", (1e-3, 1e4)),
    ("--feedback-trial-fraction", "feedback_trial_fraction", float, "fraction of trials with the stabilising PD", None),
    ("--feedback-kp", "feedback_kp_nm_per_rad", float, "PD gain on the hub angle [N m/rad]", (0.0, 1e4)),
    ("--feedback-kd", "feedback_kd_nms_per_rad", float, "PD gain on the hub rate [N m s/rad]", (0.0, 1e3)),
    ("--phi-noise-std-rad", "phi_noise_std_rad", float, "encoder noise std [rad]", (0.0, math.pi)),
    ("--tip-noise-std-m", "tip_noise_std_m", float, "camera tip-position noise std [m]", (0.0, 1.0)),
    ("--er-noise-std-rad", "er_noise_std_rad", float, "tip-rotation noise std [rad]", (0.0, math.pi)),
    ("--camera-delay-steps", "camera_delay_steps", int, "camera delay [samples]", (0, 10**6)),
)


DESCRIPTION = """Drive the simulated rod with band-limited random torques (a weak stabilising PD in most trials) and
save positions, differenced velocities and torques as a dataset (softpend.sysid.dataset)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    from softpend.sysid import BabbleProtocol

    d = BabbleProtocol()
    program = f"torque program: band-limited random torque, or a multisine to --torque-bandwidth-hz ({d.program})"
    options: list[Option] = [
        ("output", None, dict(help="dataset file to write (.npz)")),
        ("--seed", None, dict(type=int, default=0, help="seed of every random draw (default 0)")),
        ("--start", None, dict(choices=("upright", "hanging", "random"), default=d.start, help=f"start ({d.start})")),
        ("--program", None, dict(choices=("noise", "multisine"), default=d.program, help=program)),
        *field_options(d, _OPTIONS),
        ("--n-links", None, dict(type=int, default=None, help="override the number of PRB links")),
        ("--no-progress", None, dict(action="store_true", help="hide the progress bar")),
    ]
    help = "record a motor-babbling dataset (random torques near upright) for system identification"
    add_command(subparsers, "babble", help, options, run, description=DESCRIPTION)


def run(args: argparse.Namespace) -> int:
    from softpend.io.outputs import Outputs, json_text, output_name
    from softpend.plant import RodParams
    from softpend.sysid import BabbleProtocol, babble

    outputs = Outputs()  # before the work: a dataset this command wrote may be replaced, no other file
    output = str(outputs.file(output_name(args.output, ".npz", "dataset"), what="dataset"))
    protocol = BabbleProtocol(start=args.start, program=args.program, **field_values(args, _OPTIONS))
    params = RodParams() if args.n_links is None else RodParams(n_links=args.n_links)
    started = time.perf_counter()
    dataset = babble(protocol, params=params, seed=args.seed, path=output, progress=not args.no_progress)
    outputs.done(output)  # written atomically by the dataset's writer
    counts = {key: getattr(dataset, key) for key in ("n_trials", "n_samples", "n_transitions")}
    print(json_text({"path": output, **counts, "wall_s": round(time.perf_counter() - started, 2)}))
    return 0

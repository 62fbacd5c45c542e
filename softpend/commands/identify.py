"""``softpend identify``: estimate the PRB rod's physical parameters from a babbling dataset (grey-box)."""

from __future__ import annotations

import argparse

from softpend.commands.options import FieldOption, Option, add_command, field_options, field_values

#: ``(flag, GreyBoxConfig field, type, help, allowed range)``: the ranges bound the fit's loop and window draw.
_OPTIONS: tuple[FieldOption, ...] = (
    ("--window-s", "window_s", float, "shooting window [s]", (1e-6, 3600.0)),
    ("--max-windows", "max_windows", int, "most windows used", (1, 10**6)),
    ("--max-iterations", "max_iterations", int, "most Levenberg-Marquardt steps", (1, 100_000)),
    ("--seed", "seed", int, "seed of the window draw", None),
)

#: Calibration parameter -> (flag that adds it, what it is).
_CALIBRATION_FLAGS = {
    "torque_gain": ("--torque-gain", "a gain on the recorded torque"),
    "encoder_offset_rad": ("--encoder-offset", "an offset of the hub encoder"),
    "torque_delay_s": ("--torque-delay", "a delay of the torque (within one sample either way)"),
    "camera_delay_s": ("--camera-delay", "a camera delay against the encoder (within one sample; advised for rigs)"),
}


DESCRIPTION = """Fit the PRB model's physical parameters (and optional calibration terms) to a babbling dataset by
multiple shooting on the Exudyn plant; prints each estimate with its std; --out is read by RodParams.from_json."""


def register(subparsers: argparse._SubParsersAction) -> None:
    from softpend.sysid.greybox import CALIBRATION_PARAMETERS, ESTIMABLE_ROD_FIELDS, GREYBOX_PARAMETERS, GreyBoxConfig

    known = ", ".join(ESTIMABLE_ROD_FIELDS + CALIBRATION_PARAMETERS)
    options: list[Option] = [
        ("dataset", None, dict(help="dataset (.npz)")),
        ("--out", None, dict(default=None, help="JSON file to write (rod_params, estimates, std, fit)")),
        ("--parameters", None, dict(default=",".join(GREYBOX_PARAMETERS), help=f"comma-separated, from {known}")),
        *[(f, None, dict(action="store_true", help=f"also estimate {t}")) for f, t in _CALIBRATION_FLAGS.values()],
        ("--initial-params", None, dict(help="JSON file of the initial guess (default: the dataset's plant_params)")),
        *field_options(GreyBoxConfig(), _OPTIONS),
    ]
    help = "estimate the rod's physical parameters (grey-box, multiple shooting) from a dataset"
    add_command(subparsers, "identify", help, options, run, description=DESCRIPTION)


def run(args: argparse.Namespace) -> int:
    from softpend.io.outputs import Outputs, json_text
    from softpend.plant import RodParams
    from softpend.sysid import load_dataset
    from softpend.sysid.greybox import GreyBoxConfig, identify

    outputs = Outputs()
    if args.out is not None:  # before the work: a file this command wrote may be replaced, no other
        outputs.file(args.out, what="identification file")
    names = [n.strip() for n in args.parameters.split(",") if n.strip()]
    added = [n for n, (flag, _) in _CALIBRATION_FLAGS.items() if getattr(args, flag[2:].replace("-", "_"))]
    names += [n for n in added if n not in names]
    config = GreyBoxConfig(parameters=tuple(names), **field_values(args, _OPTIONS))
    dataset = load_dataset(args.dataset)
    guess = RodParams.from_json(args.initial_params) if args.initial_params else None
    result = identify(dataset, config, initial_params=guess)
    truth = dataset.params if dataset.metadata["source"] == "simulation" else None
    print(f"{'parameter':28s} {'estimate':>14s} {'std':>12s} {'initial':>12s}" + (f" {'truth':>12s}" if truth else ""))
    calibration = {name: 0.0 for name in _CALIBRATION_FLAGS} | {"torque_gain": 1.0}  # a simulation's truth
    for name, value in result.estimates.items():
        rods = (result.initial_params, truth or result.initial_params)
        known = [calibration[name] if name in calibration else getattr(rod, name) for rod in rods]
        line = f"{name:28s} {value:14.6g} {result.std[name]:12.3g} {known[0]:12.6g}"
        print(line + (f" {known[1]:12.6g}" if truth else ""))
    print(
        f"{result.n_windows} windows of {result.window_steps} samples, residual RMS {result.residual_rms_rad:.3g} rad, "
        f"{result.njev} Jacobians, {result.identify_s:.1f} s: {result.message}"
    )
    if result.at_bounds:
        print(f"on a bound of the search (not determined by the data): {', '.join(result.at_bounds)}")
    if args.out is not None:
        outputs.write_text(args.out, json_text(result.to_dict(), indent=2) + "\n")
        print(f"wrote {args.out}")
    return 0

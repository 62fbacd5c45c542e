"""``softpend rig control CONTROLLER``: run a controller on a rig (a serial port) or on the digital twin.

CONTROLLER is a built-in controller (``planner``: the MPPI planner of ``book/hparams/planner.yml``, learned in
simulation first) or a DQN, DQN-MBPO or PILCO run folder; it runs behind the state estimator, logs in ``--out``."""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from softpend.commands.options import MAX_SESSION_S, Option, add_command, add_target, camera_source
from softpend.plant.params import MAX_N_LINKS

#: ``--camera-effects`` names: no imperfection, or the CameraEffects class method of that name.
CAMERA_EFFECTS = ("clean", "rig", "noisy")

BUILTIN_CONTROLLERS = ("lqr", "lqr-obs", "swingup", "swingup-obs", "pid", "planner")

OPTIONS: tuple[Option, ...] = (
    ("controller", None, dict(metavar="CONTROLLER", help=f"{', '.join(BUILTIN_CONTROLLERS)} or a run folder")),
    ("--out", None, dict(required=True, metavar="DIR", help="folder for the logs and summary.json")),
    ("--duration", (1e-3, MAX_SESSION_S), dict(type=float, default=10.0, help="run length [s] (default 10)")),
    ("--camera", None, dict(metavar="CAMERA", help="with --port: camera index, stream URL or video file")),
    ("--no-camera", None, dict(action="store_true", help="encoder and model only (no blindness limit)")),
    ("--camera-fps", (1.0, 1000.0), dict(type=float, default=60.0, help="twin camera frame rate (default 60)")),
    ("--camera-latency-ms", (0.0, 1000.0), dict(type=float, default=20.0, help="exposure end to host [ms] (20)")),
    ("--camera-effects", None, dict(choices=sorted(CAMERA_EFFECTS), default="rig", help="twin camera defects (rig)")),
    ("--markers", None, dict(metavar="JSON", help="with --camera: marker positions [m] (default layout)")),
    ("--calibration", None, dict(metavar="JSON", help="with --camera: a saved AffineCalibration")),
    ("--max-blind-ms", (1.0, 60_000.0), dict(type=float, default=300.0, help="longest time without a camera fix [ms]")),
    ("--start", None, dict(choices=("hanging", "upright"), default="hanging", help="twin: start (hanging)")),
    ("--tilt", (-math.pi, math.pi), dict(type=float, default=0.1, help="twin, --start upright: tilt [rad] (0.1)")),
    ("--start-noise", (0.0, math.pi), dict(type=float, default=0.05, help="twin: uniform start noise [rad, rad/s]")),
    ("--seed", None, dict(type=int, default=0, help="twin: seed of the start noise and the camera noise")),
    ("--latency-ms", (0.0, 1000.0), dict(type=float, default=2.0, help="twin: one-way link latency [ms] (2)")),
    ("--counts-per-rev", (4, 2**24), dict(type=int, default=4096, help="encoder resolution (4096)")),
    ("--n-links", (1, MAX_N_LINKS), dict(type=int, help="PRB links of the model (default: the run folder's, else 4)")),
    ("--which", None, dict(choices=("best", "final"), default="best", help="DQN run: which agent")),
    ("--pid-gains", (-1e6, 1e6), dict(type=float, nargs=3, metavar=("KP", "KI", "KD"), help="pid: gains (tuned)")),
    ("--no-progress", None, dict(action="store_true", help="hide the progress bar")),
    ("--json", None, dict(action="store_true", help="print the summary as JSON")),
)


def register(subparsers: argparse._SubParsersAction) -> None:
    help = "run a controller on a rig (--port) or on the digital twin (--twin), camera in the loop"
    add_target(add_command(subparsers, "control", help, OPTIONS, run, description=__doc__.split("\n\n")[0]))


def build_controller(
    spec: str, task, which: str = "best", pid_gains=None, planner_overrides=None, progress: bool = False
) -> tuple[Any, Any, str]:
    """``(controller, task, label)`` for a controller name or run folder (with its own task); the planner
    (``planner_overrides``) is a :class:`softpend.study.rig_runs.TimedController` (``info``: plant seconds learned)."""
    from softpend.control.lqr import LQRController
    from softpend.control.pid import PIDController, PIDGains, plant_simulator, tune_pid
    from softpend.control.swingup import EnergySwingUpController

    rod, dt, swingup = task.rod, task.dt_s, "energy swing-up + LQR"
    builtin = {
        "lqr": lambda: (LQRController.from_params(rod, dt, state="joint"), "LQR (joint state)"),
        "lqr-obs": lambda: (LQRController.from_params(rod, dt, state="observation"), "LQR (observations)"),
        "swingup": lambda: (EnergySwingUpController(rod, dt_s=dt), swingup),
        "swingup-obs": lambda: (EnergySwingUpController.for_observations(rod, dt_s=dt), f"{swingup} (observations)"),
    }
    if spec in builtin:
        controller, label = builtin[spec]()
        return controller, task, label
    if spec == "pid":
        if pid_gains is None:
            gains = tune_pid(plant_simulator(task), torque_limit_nm=rod.torque_limit_nm, max_evaluations=60).gains
        else:
            gains = PIDGains(*pid_gains)
        return PIDController(gains, dt_s=dt, torque_limit_nm=rod.torque_limit_nm), task, f"PID {gains}"
    if spec == "planner":
        from softpend.control.planner import run_planner
        from softpend.study.data_efficiency import planner_config
        from softpend.study.rig_runs import PLANNER, TimedController

        result = run_planner(planner_config(task, planner_overrides), progress=progress)
        label = f"{PLANNER}, learned in {result.plant_seconds:.2f} plant s"
        return TimedController(result.controller, {"planner_plant_s": result.plant_seconds}), task, label
    if not Path(spec).exists():
        raise ValueError(f"controller must be one of {', '.join(BUILTIN_CONTROLLERS)} or a run folder, got {spec!r}")
    from softpend.study.rig_runs import learned_controller

    return learned_controller(spec, which)


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from softpend.hardware.closed_loop import TWIN_CONTROL_FILES, TwinCamera, run_twin_control
    from softpend.hardware.emulator import RigConfig
    from softpend.hardware.estimator import EstimatorConfig
    from softpend.io.outputs import Outputs, json_text
    from softpend.study.rig_runs import TimedController, run_truth_metrics, step_time_figures, torque_chatter_nm_per_s
    from softpend.task import Task
    from softpend.vision.camera import CameraEffects

    if args.twin and args.camera:
        raise ValueError("--camera is for --port; the twin films itself with the synthetic camera")
    if args.port and not (args.camera or args.no_camera):
        raise ValueError("--port needs --camera (index, URL or video file) or --no-camera")
    outputs = Outputs()
    out = outputs.folder(args.out, TWIN_CONTROL_FILES if args.twin else PORT_CONTROL_FILES, what="--out")
    progress = not args.no_progress

    def ours(task: Task) -> Task:  # the start noise and link count of the options (a run folder brings its task)
        task = task.replace(start_noise_rad=args.start_noise)
        return task if args.n_links in (None, task.rod.n_links) else task.replace(n_links=args.n_links)

    spec, base = args.controller, ours(Task())
    controller, task, label = build_controller(spec, base, args.which, args.pid_gains, progress=progress)
    if not isinstance(controller, TimedController):
        controller = TimedController(controller)
    task = ours(task)
    estimator_config = EstimatorConfig(counts_per_rev=args.counts_per_rev, max_blind_s=args.max_blind_ms / 1000.0)
    if args.twin:
        upright = args.start == "upright"
        rig = RigConfig(task, counts_per_rev=args.counts_per_rev, latency_s=args.latency_ms / 1000.0, seed=args.seed)
        rig = dataclasses.replace(rig, initial_tilt_rad=args.tilt if upright else None, hold_until_commanded=upright)
        name, latency_s = args.camera_effects, args.camera_latency_ms / 1000.0
        effects = CameraEffects() if name == "clean" else getattr(CameraEffects, name)()
        camera = TwinCamera(args.camera_fps, latency_s, effects, seed=args.seed) if not args.no_camera else None
        run = dict(progress=progress, outputs=outputs, camera_wait_s=1.0 + latency_s + 2.0 / args.camera_fps)
        outcome = run_twin_control(controller, out, args.duration, rig, camera, estimator_config, **run)
        target, figures = "twin", outcome.result.summary()
        truth = run_truth_metrics(outcome.motor_log, outcome.truth_log, task)
        extra = {"truth": truth, "emulator": outcome.emulator_stats}
    else:
        target, extra = args.port, {}
        figures = _run_on_port(args, controller, task, estimator_config, out, progress, outputs)
    chatter = torque_chatter_nm_per_s(out / "motor_log.csv")
    steps = {**controller.info, **step_time_figures(controller.step_ms, task.dt_s)}
    summary = {"controller": label, "target": target, **figures, "torque_chatter_nm_per_s": chatter, **steps, **extra}
    outputs.write_json(out / "summary.json", summary)
    if args.json:
        print(json_text(summary, indent=2))
    else:
        print(
            f"{label}: {summary['samples']} samples over {summary['duration_s']:.2f} s, "
            f"{'stopped: ' + summary['stop_reason'] if summary['stop_reason'] else 'completed'}; "
            + ("" if args.twin else f"loop jitter p95 {summary['jitter_ms_p95']:.2f} ms; ")
            + f"controller step p95 {summary['step_ms_p95']:.2f} ms of a {summary['control_period_ms']:.1f} ms period; "
            + f"logs in {out}"
        )
        if t := summary.get("truth"):
            print(
                f"truth: swing-up {t['swing_up_time_s']:.2f} s, upright std {t['upright_std_rad']:.3f} rad, "
                f"peak torque {t['peak_torque_nm']:.3f} N m, success {t['success']}"
            )
    return 0 if summary["stop_reason"] is None else 1


#: The files ``softpend rig control --port`` writes in ``--out``.
PORT_CONTROL_FILES = ("motor_log.csv", "camera_log.csv", "summary.json")


def _run_on_port(args, controller, task, estimator_config, out: Path, progress: bool, outputs) -> dict:
    from softpend.hardware.closed_loop import CAMERA_LOG_COLUMNS, rig_control_columns, run_closed_loop
    from softpend.hardware.driver import MotorLink
    from softpend.hardware.estimator import RigStateEstimator
    from softpend.io.samplelog import SampleLog

    estimator, source = RigStateEstimator(task, estimator_config), None if args.no_camera else camera_source(args)
    metadata = {"task": task.to_dict(), "port": args.port, "camera": args.camera}
    logs = [outputs.live(out / name) for name in PORT_CONTROL_FILES[:2]]
    try:
        if source is not None:
            source.start()
        with (
            MotorLink(args.port, torque_limit_nm=task.torque_limit_nm) as link,
            SampleLog(out / "motor_log.csv", rig_control_columns(estimator.n), metadata=metadata) as log,
            SampleLog(out / "camera_log.csv", CAMERA_LOG_COLUMNS, metadata=metadata) as camera_log,
        ):
            result = run_closed_loop(link, controller, estimator, args.duration, source, log, camera_log, progress)
    finally:
        if source is not None:
            source.close()
        for path in logs:
            outputs.done(path)
    return result.summary()

"""``softpend rig design | check | calibrate | babble``: take a rig (``--port``, ``--camera``) or the twin to data."""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import Any

from softpend.commands.options import MAX_SESSION_S, Option, add_command, add_target, camera_source, set_option

#: Accepted ``--print-modulus-mpa`` [MPa]: soft silicone to steel.
PRINT_MODULUS_RANGE_MPA = (0.1, 3.0e5)
ROD_SET = set_option("set a RodParams field of the rod (VALUE parsed as JSON), e.g. --set length_m=0.4; repeatable")


def register(actions: argparse._SubParsersAction) -> None:
    modulus = "modulus of the beam's material [MPa] (default: the rod's youngs_modulus_pa)"
    design: list[Option] = [
        ("--out", None, dict(required=True, metavar="DIR", help="folder for rig_design.json/.png, markers.json")),
        ("--print-modulus-mpa", PRINT_MODULUS_RANGE_MPA, dict(type=float, default=None, help=modulus)),
        ROD_SET,
    ]
    help = "the rig's dimensions, drawing and marker layout for the rod's parameters"
    add_command(actions, "design", help, design, run_design)
    push = "torque of the direction push as a fraction of the torque limit (0.3)"
    check: list[Option] = [
        ("--out", None, dict(metavar="JSON", help="also write the report to this file")),
        ("--rest-s", (0.1, 600.0), dict(type=float, default=1.0, help="zero-torque time of the rest check [s] (1)")),
        ("--counts-per-rev", (4, 2**24), dict(type=int, default=4096, help="twin: encoder resolution (4096)")),
        ("--push-fraction", None, dict(type=float, default=0.3, help=push)),
        ROD_SET,
    ]
    help = "power-on checks of the motor link: handshake, rest, direction, watchdog"
    add_target(add_command(actions, "check", help, check, run_check), "--port")
    markers = "marker positions [m], JSON list [[x, y], ...] or file (softpend rig design's markers.json)"
    calibrate: list[Option] = [
        ("--markers", None, dict(required=True, metavar="JSON", help=markers)),
        ("--out", None, dict(required=True, metavar="JSON", help="calibration file to write (and NAME.report.json)")),
        ("--seed", None, dict(type=int, default=0, help="twin: seed of the image noise")),
        ROD_SET,
    ]
    help = "fit the camera's pixel-to-metre map to the markers and save it"
    add_target(add_command(actions, "calibrate", help, calibrate, run_calibrate), "--camera")
    babble: list[Option] = [
        ("--camera", None, dict(metavar="CAMERA", help="with --port: camera index, stream URL or video file")),
        ("--markers", None, dict(metavar="JSON", help="with --camera: marker positions [m] (default layout)")),
        ("--calibration", None, dict(metavar="JSON", help="with --camera: a saved calibration")),
        ("--out", None, dict(required=True, metavar="DIR", help="folder for the logs, the dataset and summary.json")),
        ("--camera-latency-ms", (0.0, 1000.0), dict(type=float, default=0.0, help="with --camera: latency [ms] (0)")),
        ("--duration", (1e-3, MAX_SESSION_S), dict(type=float, default=65.0, help="babbling time [s] (65)")),
        ("--trial-length-s", (0.1, MAX_SESSION_S), dict(type=float, default=5.0, help="trial length [s] (5)")),
        ("--seed", None, dict(type=int, default=0, help="seed of the babbling torques (and of the twin)")),
        ("--no-progress", None, dict(action="store_true", help="hide the progress bars")),
    ]
    help = "babble over the link with the camera tracking, synchronise into a dataset"
    add_target(add_command(actions, "babble", help, babble, run_babble), "--port")


def _rod(args: argparse.Namespace):
    from softpend.io.overrides import apply_overrides
    from softpend.plant import RodParams

    return apply_overrides(RodParams(), args.overrides)


def run_design(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from softpend.hardware.rig_design import rig_design
    from softpend.io.outputs import Outputs, finite_or_none
    from softpend.study.build_rig import design_figures
    from softpend.study.figures.rig_design import draw_rig_design

    modulus = None if args.print_modulus_mpa is None else args.print_modulus_mpa * 1e6
    outputs = Outputs()
    out = outputs.folder(args.out, ("rig_design.json", "markers.json", "rig_design.png"), what="--out")
    params = _rod(args)
    design = rig_design(params, print_modulus_pa=modulus)
    figures = design_figures(params, design)
    outputs.write_json(out / "rig_design.json", finite_or_none(figures))
    outputs.write_json(out / "markers.json", finite_or_none(figures["markers_m"]))
    fig = draw_rig_design(design)
    with outputs.open(out / "rig_design.png") as handle:
        fig.savefig(handle, format="png", dpi=120)
    plt.close(fig)
    print(
        f"beam {figures['beam_length_mm']:.1f} x {figures['beam_width_mm']:.1f} x {figures['beam_thickness_mm']:.2f} mm, "
        f"camera {figures['camera_distance_mm']:.0f} mm from the plane ({figures['pixel_size_mm']:.2f} mm/px), "
        f"clamped-horizontal tip sag {figures['tip_sag_horizontal_mm']:.1f} mm -> {out}"
    )
    return 0


def run_check(args: argparse.Namespace) -> int:
    from softpend.hardware.emulator import RigConfig, SimRig
    from softpend.io.outputs import Outputs, finite_or_none
    from softpend.task import Task

    outputs = Outputs()
    if args.out is not None:  # an empty --out is an error, not no report
        outputs.file(args.out, what="--out")
    if not 0 < args.push_fraction <= 0.5:
        raise ValueError(f"--push-fraction must lie in (0, 0.5], got {args.push_fraction!r}")
    task = Task(rod=_rod(args), start_noise_rad=0.0)
    rig = SimRig(RigConfig(task=task, counts_per_rev=args.counts_per_rev)) if args.twin else None
    report = rig_check(
        "twin" if args.twin else args.port, task, args.rest_s, args.push_fraction, serial=rig and rig.connect()
    )
    if rig is not None:
        rig.close()
    if args.out is not None:
        outputs.write_json(args.out, finite_or_none(report))
    for name, check in report["checks"].items():
        print(f"{'ok  ' if check['passed'] else 'FAIL'} {name}: {check['detail']}")
    return 0 if report["passed"] else 1


#: States by which the watchdog's trip may differ from its nominal time.
WATCHDOG_SLACK_STATES = 3


def rig_check(port: str, task, rest_s: float, push_fraction: float, serial=None) -> dict:
    """The report of the power-on checks on the link at ``port`` (or the twin's in-memory ``serial``)."""
    import numpy as np

    from softpend.hardware import protocol
    from softpend.hardware.driver import MotorLink

    rod, checks = task.rod, dict[str, dict]()

    def check(name: str, ok: Any, detail: str, **figures: float) -> None:
        checks[name] = {"passed": bool(ok), "detail": detail, **figures}

    with MotorLink(port, torque_limit_nm=rod.torque_limit_nm, serial=serial) as link:
        info = link.device
        assert info is not None  # the handshake on opening the link sets it
        rtt, rate, limit = float(np.median([link.ping() for _ in range(5)])), 1.0 / task.dt_s, rod.torque_limit_nm
        watchdog_ms, tick = info.watchdog_s * 1e3, 2 * math.pi / info.counts_per_rev
        ok = info.protocol_version == protocol.PROTOCOL_VERSION and info.watchdog_s <= 0.1 + 1e-9
        ok &= math.isclose(info.torque_limit_nm, limit, rel_tol=1e-5)
        ok &= math.isclose(info.state_rate_hz, rate, rel_tol=1e-6)
        detail = (
            f"protocol {info.protocol_version} (host {protocol.PROTOCOL_VERSION}), torque limit "
            f"{info.torque_limit_nm:g} N m (rod {limit:g}), {info.state_rate_hz:g} states/s (host {rate:g}), watchdog "
            f"{watchdog_ms:g} ms (at most 100), {info.counts_per_rev} counts/rev, round trip {rtt * 1e3:.2f} ms"
        )
        check("handshake", ok, detail)

        link.drain_states()
        rest = _states_for(link, rest_s)
        phi = np.array([s.phi_rad for s in rest])
        period = float(np.median(np.diff([s.device_time_s for s in rest]))) if len(rest) > 2 else math.nan
        offset = float(np.mean(phi) - math.pi) if len(phi) else math.nan
        spread = float((phi.max() - phi.min()) / tick) if len(phi) else math.nan
        ok = len(rest) > 2 and abs(period * rate - 1) < 0.1 and abs(offset) <= 0.05 and spread <= 3
        detail = (
            f"{len(rest)} states in {rest_s:g} s (period {period * 1e3:.2f} ms), hub {offset:+.4f} rad from hanging, "
            f"spread {spread:.0f} ticks"
        )
        check("rest", ok, detail, offset_rad=offset, spread_ticks=spread)

        push = push_fraction * limit
        moved = _states_for(link, 0.15, push)
        delta = (moved[-1].phi_rad - (phi[-1] if len(phi) else math.pi)) if moved else math.nan
        applied = max((s.applied_torque_nm for s in moved), default=math.nan)
        _states_for(link, 1.0, 0.0)  # let the swing settle, feeding the watchdog with zero torque
        detail = (
            f"a push of {push:+.3g} N m for 0.15 s turned the hub {delta:+.4f} rad (positive expected), device "
            f"applied {applied:+.3g} N m"
        )
        check("direction", delta > tick and math.isclose(applied, push, rel_tol=1e-3), detail, delta_rad=delta)

        last_seq = link.send_torque(0.0)
        silence = _states_for(link, 3 * info.watchdog_s + 0.2)
        # on the device's clock: from the first state that shows the last command in force to the first trip
        in_force = next((s.device_time_s for s in silence if s.last_cmd_seq == last_seq), math.nan)
        tripped = [s for s in silence if s.watchdog_tripped and s.device_time_s >= in_force]
        trip_ms = (tripped[0].device_time_s - in_force) * 1e3 if tripped else math.nan
        zero = bool(tripped) and all(s.applied_torque_nm == 0.0 for s in tripped)
        slack_ms = WATCHDOG_SLACK_STATES * 1e3 / info.state_rate_hz
        detail = (
            f"tripped {trip_ms:.0f} ms (device clock) after the last command took effect (watchdog {watchdog_ms:g} "
            f"ms, within {slack_ms:.0f} ms passes), torque {'zero' if zero else 'NOT zero'} after the trip"
        )
        check("watchdog", zero and watchdog_ms - slack_ms <= trip_ms <= watchdog_ms + slack_ms, detail, trip_ms=trip_ms)
        link.stop()
    device = ("protocol_version", "counts_per_rev", "torque_limit_nm", "watchdog_s", "state_rate_hz")
    report: dict[str, Any] = {"port": port, "device": {k: getattr(info, k) for k in device}, "round_trip_ms": rtt * 1e3}
    return report | {"checks": checks, "passed": all(c["passed"] for c in checks.values())}


def _states_for(link, duration_s: float, torque_nm: float | None = None) -> list:
    """The states received in ``duration_s``, commanding ``torque_nm`` (if given) at every state."""
    end = link.clock.now_s() + duration_s
    states = []
    if torque_nm is not None:
        link.send_torque(torque_nm)
    while link.clock.now_s() < end:
        states.append(link.read_state())
        if torque_nm is not None:
            link.send_torque(torque_nm)
    return states


def run_calibrate(args: argparse.Namespace) -> int:
    import numpy as np

    from softpend.io.outputs import Outputs, finite_or_none
    from softpend.study.build_rig import CALIBRATION_MAX_RESIDUAL_PX, HANGING_TIP_TOLERANCE_M
    from softpend.vision.calibration import calibrate_from_markers, read_markers
    from softpend.vision.tracker import TipTracker

    outputs = Outputs()
    out = outputs.file(args.out, what="--out")
    report_path = outputs.file(out.with_name(f"{out.stem}.report.json"), what="the calibration report")
    markers = np.array(read_markers("--markers", args.markers or "[]"))
    params = _rod(args)
    frame = _twin_frame(params, markers, args.seed) if args.twin else _grab_frame(args.camera)
    calibration = calibrate_from_markers(frame, markers.tolist())
    detection = TipTracker(search_radius_px=None).track(frame)
    expected = np.array([0.0, -params.length_m])
    if detection.lost:
        tip, error = [math.nan, math.nan], math.inf
    else:
        tip_m = calibration.to_metres(np.array([detection.x_px, detection.y_px]))
        tip, error = tip_m.tolist(), float(np.hypot(*(tip_m - expected)))
    residual_px = calibration.residual_rms_m / calibration.metres_per_pixel
    passed = residual_px <= CALIBRATION_MAX_RESIDUAL_PX and error <= HANGING_TIP_TOLERANCE_M
    outputs.write_text(out, calibration.to_json())
    report: dict[str, Any] = dict(calibration=str(out), residual_px=residual_px, residual_m=calibration.residual_rms_m)
    report |= dict(px_per_m=1.0 / calibration.metres_per_pixel, hub_px=calibration.to_pixels(np.zeros(2)).tolist())
    report |= dict(tip_m=tip, expected_tip_m=expected.tolist(), tip_error_m=error, passed=bool(passed))
    outputs.write_json(report_path, finite_or_none(report))
    print(
        f"{'ok  ' if passed else 'FAIL'} markers fit to {residual_px:.3f} px RMS (at most {CALIBRATION_MAX_RESIDUAL_PX:g}), "
        f"{report['px_per_m']:.1f} px/m; hanging tip {error * 1e3:.2f} mm from the design's (at most "
        f"{HANGING_TIP_TOLERANCE_M * 1e3:g}) -> {out}"
    )
    return 0 if passed else 1


def _twin_frame(params, markers, seed: int):
    """A synthetic-camera frame (the design's scene, a slight roll) of the rod hanging at rest."""
    import dataclasses

    import numpy as np

    from softpend.hardware.rig_design import rig_design
    from softpend.task import Task
    from softpend.vision.camera import CameraEffects, CameraModel, SyntheticCamera

    model = dataclasses.replace(rig_design(params).camera_model, roll_rad=CameraModel().roll_rad)
    camera = SyntheticCamera(model=model, effects=CameraEffects.rig(), markers_m=markers, seed=seed)
    plant = Task(rod=params).make_plant()
    q, _ = plant.hanging_state()
    points = plant.link_points_m(q)
    times = np.array([0.0, 1.0])
    ((frame, _),) = camera.frames(times, np.stack([points, points]), times[1:], np.array([q[0], q[0]]))
    return frame


def _grab_frame(camera: str):
    """The tenth frame of a camera (the first ones settle exposure), or an image file."""
    import itertools

    import cv2

    from softpend.io.reading import check_capture_path
    from softpend.vision.tip_source import MAX_DEVICE_INDEX

    check_capture_path("--camera", camera)
    if Path(camera).is_file() and cv2.haveImageReader(camera):
        if (image := cv2.imread(camera)) is None:
            raise ValueError(f"--camera {camera}: the image cannot be read")
        return image
    device: int | str = int(camera) if camera.strip().isdigit() else camera
    if isinstance(device, int) and device > MAX_DEVICE_INDEX:  # OpenCV takes a C int
        raise ValueError(f"--camera index must lie in [0, {MAX_DEVICE_INDEX}], got {camera!r}")
    capture = cv2.VideoCapture(device)
    try:
        if not capture.isOpened():
            raise ValueError(f"--camera {camera} cannot be opened")
        reads = list(itertools.takewhile(lambda read: read[0], (capture.read() for _ in range(10))))
        frame = reads[-1][1] if reads else None
    finally:
        capture.release()
    if frame is None:
        raise ValueError(f"--camera {camera} delivered no frame")
    return frame


def run_babble(args: argparse.Namespace) -> int:
    from softpend.hardware.emulator import RigConfig
    from softpend.hardware.twin import _OUTPUTS, run_twin_session
    from softpend.io.outputs import Outputs, finite_or_none
    from softpend.task import Task

    if args.twin and (args.camera or args.markers or args.calibration):
        raise ValueError("--camera, --markers and --calibration are for --port; the twin films itself")
    if args.port and not args.camera:
        raise ValueError("--port needs --camera (index, URL or video file)")
    if not (math.isfinite(args.duration) and args.duration >= args.trial_length_s + 3):
        raise ValueError(f"--duration must be at least --trial-length-s + 3 s, got {args.duration!r}")
    outputs = Outputs()
    out = outputs.folder(args.out, (*(_OUTPUTS if args.twin else PORT_BABBLE_FILES), "summary.json"), what="--out")
    progress = not args.no_progress
    extra = {}
    if args.twin:
        rig, length = RigConfig(task=Task(start_noise_rad=0.0), seed=args.seed), args.trial_length_s
        run = dict(rig=rig, trial_length_s=length, progress=progress, outputs=outputs)
        session = run_twin_session(out, args.duration, args.seed, **run)
        loop, sync, dataset = session.loop, session.sync, session.dataset
        extra["true_clock_offset_s"] = session.true_clock_offset_s
    else:
        loop, sync, dataset = _babble_on_port(args, out, progress, outputs)
    summary: dict[str, Any] = {"dataset": str(out / "rig_dataset.npz"), "n_trials": dataset.n_trials}
    summary |= {key: getattr(loop, key) for key in ("samples", "dropped_states", "jitter_ms_p95")}
    summary |= dict(clock_offset_s=sync.offset.offset_s, peak_correlation=sync.offset.peak_correlation)
    summary |= dict(gaps=len(sync.gaps), grid_valid_fraction=sync.grid_valid_fraction, **extra)
    outputs.write_json(out / "summary.json", finite_or_none(summary))
    print(
        f"{summary['n_trials']} trials x {args.trial_length_s:g} s, clock offset {summary['clock_offset_s'] * 1e3:.1f} ms "
        f"(correlation {summary['peak_correlation']:.3f}), {summary['gaps']} gaps -> {summary['dataset']}"
    )
    return 0


#: The files ``softpend rig babble --port`` writes in ``--out`` besides ``summary.json``.
PORT_BABBLE_FILES = ("camera.csv", "motor_log.csv", "rig_dataset.npz")


def _babble_on_port(args: argparse.Namespace, out: Path, progress: bool, outputs):
    """Babble on the rig at ``args.port`` while a thread tracks ``args.camera``; synchronise the logs."""
    import threading

    from softpend.hardware.closed_loop import LOOP_LOG_COLUMNS, run_control_loop
    from softpend.hardware.driver import MotorLink
    from softpend.hardware.sync import build_rig_dataset
    from softpend.hardware.twin import rig_babble_controller
    from softpend.io.samplelog import SampleLog
    from softpend.plant import RodParams
    from softpend.vision.track_video import track_live

    files = [outputs.live(out / name) for name in PORT_BABBLE_FILES]
    source, camera_csv, motor_log = camera_source(args), out / "camera.csv", out / "motor_log.csv"
    failure: list[BaseException] = []

    def film() -> None:
        try:
            track_live(source, camera_csv, duration_s=args.duration + 2.0)
        except BaseException as exc:  # re-raised in the main thread below
            failure.append(exc)

    params = RodParams()
    thread = threading.Thread(target=film, name="softpend-babble-camera", daemon=True)
    thread.start()
    time.sleep(1.0)  # the camera runs before the first torque, so the start-up wiggle is filmed whole
    controller = rig_babble_controller(args.duration, params.torque_limit_nm, args.seed)
    with (
        MotorLink(args.port, torque_limit_nm=params.torque_limit_nm) as link,
        SampleLog(motor_log, LOOP_LOG_COLUMNS, metadata={"port": args.port}) as log,
    ):
        loop = run_control_loop(link, controller, args.duration, log=log, progress=progress)
    thread.join()
    if failure:
        raise failure[0]
    settings = dict(params=params, trial_length_s=args.trial_length_s, notes=f"rig babbling on {args.port}")
    dataset, sync = build_rig_dataset(motor_log, camera_csv, out / "rig_dataset.npz", **settings)
    for path in files:
        outputs.done(path)
    return loop, sync, dataset

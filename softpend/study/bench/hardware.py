"""Hardware-rig figures (``softpend bench --only hardware``): tracker speed and accuracy, rig loop jitter."""

from __future__ import annotations

import numpy as np

from softpend.study.bench import best_times

N_FRAMES = 300
LOOP_SECONDS = 5.0


def _tracker_figures(effects, seed: int, trajectory) -> tuple[float, float, float, float]:
    """(RMS error [px], frames/s with the search window, frames/s searching whole frames, lost frames)."""
    from softpend.vision.accuracy import tracking_errors
    from softpend.vision.tracker import TipTracker

    errors, frames = tracking_errors(trajectory, effects, N_FRAMES, seed, keep_frames=True)
    fps = []
    for radius in (TipTracker().search_radius_px, None):  # the search window, whole frames
        track = lambda: list(map(TipTracker(search_radius_px=radius).track, frames))  # noqa: E731,B023  (a fresh tracker)
        fps.append(len(frames) / best_times(track, 3)[0])
    return errors.rmse_px, fps[0], fps[1], float(errors.lost.sum())


def _rig_loop_jitter() -> dict[str, float]:
    """Command-period figures of the closed loop against the emulator in its own process on a pseudo-terminal."""
    from softpend.control.swingup import EnergySwingUpController
    from softpend.hardware.closed_loop import run_closed_loop
    from softpend.hardware.driver import MotorLink
    from softpend.hardware.emulator import EmulatorProcess, RigConfig
    from softpend.hardware.estimator import RigStateEstimator

    rig = RigConfig()
    task, controller = rig.task, EnergySwingUpController(rig.task.rod, dt_s=rig.task.dt_s)
    with EmulatorProcess(rig) as emulator:
        with MotorLink(emulator.port, torque_limit_nm=task.torque_limit_nm, timeout_s=1.0) as link:
            result = run_closed_loop(link, controller, RigStateEstimator(task), LOOP_SECONDS)
    periods_ms = result.command_periods_s * 1e3
    return {
        "rig_loop_jitter_ms": result.jitter_ms_p95,
        "rig_loop_period_ms_mean": float(np.mean(periods_ms)),
        "rig_loop_period_ms_max": float(np.max(periods_ms)),
        "rig_loop_late_command_fraction": result.late_commands / max(result.samples, 1),
        "rig_loop_dropped_states": float(result.dropped_states),
    }


def bench_hardware() -> dict[str, float]:
    """Tracker speed and accuracy on clean and noisy rendered frames, and the rig loop's jitter."""
    import cv2

    from softpend.vision.accuracy import babbling_trajectory
    from softpend.vision.camera import CameraEffects

    cv2.setNumThreads(1)
    trajectory = babbling_trajectory(N_FRAMES + 2)
    out: dict[str, float] = {}
    for name, effects, seed in (("clean", CameraEffects(), 0), ("noisy", CameraEffects.noisy(), 1)):
        fps = "tracker_fps_640x480" + ("_noisy" if seed else "")
        rmse, out[fps], out[f"{fps}_full_frame"], lost = _tracker_figures(effects, seed, trajectory)
        out[f"tracker_rmse_px_{name}"], out[f"tracker_lost_frames_{name}"] = rmse, lost
    return out | _rig_loop_jitter()

"""A rig session on the digital twin: babble over the emulated link, film the true motion on an offset clock,
track the video, synchronise both logs into a ``source="rig"`` dataset."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Optional

import numpy as np

from softpend.hardware.closed_loop import LOOP_LOG_COLUMNS, LoopResult, RigObservation, run_control_loop
from softpend.hardware.driver import MotorLink
from softpend.hardware.emulator import RigConfig, SimRig
from softpend.hardware.sync import SyncResult, build_rig_dataset, startup_wiggle_torque
from softpend.io.samplelog import SampleLog, read_sample_log
from softpend.plant import RodParams, make_plant

if TYPE_CHECKING:
    from softpend.sysid.dataset import TrajectoryDataset

__all__ = ["TwinSession", "rig_babble_controller", "run_twin_session", "truth_link_points"]


def rig_babble_controller(
    duration_s: float, torque_limit_nm: float, seed: int, program: Optional[np.ndarray] = None
) -> Callable[[RigObservation, float], float]:
    """The rig's babbling program, a function of time every 0.01 s: the start-up wiggle (2 s at 0.8 of the limit),
    then band-limited Gaussian torque (std half the limit, 2 Hz), or the torques ``program`` [N m] then zero."""
    from softpend.sysid.babble import band_limited_noise

    dt_s, n = 0.01, int(math.ceil((duration_s + 1.0) / 0.01))
    wiggle = startup_wiggle_torque(2.0, 0.8 * torque_limit_nm, seed=seed + 1, dt_s=dt_s)
    if program is None:
        noise = band_limited_noise(np.random.default_rng(seed), n, 0.5 * torque_limit_nm, 2.0, dt_s)
    else:
        noise = np.append(np.asarray(program, dtype=float), 0.0)
    sequence = np.concatenate([wiggle, noise])

    def controller(observation: RigObservation, time_s: float) -> float:
        return float(sequence[min(int(time_s / dt_s + 0.5), len(sequence) - 1)])

    return controller


def truth_link_points(
    truth_log: str | Path, params: RodParams, plant: str = "prb"
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Device times, points along the rod ``(T, k, 2)`` and hub angles from an emulator truth log of ``plant``."""
    log = read_sample_log(truth_log)
    model = make_plant(plant, params=params)
    n = model.n_coordinates
    q = np.column_stack([log[f"q{i}_rad"] for i in range(n)])
    points = np.stack([model.link_points_m(row) for row in q])
    return log["device_time_s"], points, q[:, 0]


@dataclass
class TwinSession:
    """Paths and figures of one end-to-end twin session."""

    workdir: Path
    motor_log: Path
    truth_log: Path
    video: Path
    camera_csv: Path
    dataset_path: Path
    loop: LoopResult
    sync: SyncResult
    dataset: TrajectoryDataset
    true_clock_offset_s: float
    emulator_stats: dict = field(default_factory=dict)


def run_twin_session(
    workdir: str | Path,
    duration_s: float = 30.0,
    seed: int = 0,
    rig: Optional[RigConfig] = None,
    clock_offset_s: float = 0.137,
    trial_length_s: float = 5.0,
    progress: bool = True,
    outputs: Optional[Any] = None,
    program: Optional[np.ndarray] = None,
) -> TwinSession:
    """Run the rig pipeline on the twin into ``workdir`` (``seed``: torques, emulator, camera; ``clock_offset_s``:
    camera minus motor clock; ``program``: torques after the wiggle, :func:`rig_babble_controller`)."""
    from softpend.io.outputs import Outputs
    from softpend.vision.camera import CameraEffects, SyntheticCamera, render_video
    from softpend.vision.track_video import track_video

    if not (math.isfinite(duration_s) and duration_s >= trial_length_s + 3):
        raise ValueError(f"duration_s must be at least trial_length_s + 3 s, got {duration_s!r}")

    outputs = outputs if outputs is not None else Outputs()
    workdir = outputs.folder(workdir, _OUTPUTS, what="workdir")
    rig = rig if rig is not None else RigConfig(seed=seed)
    motor_log, truth_log, video, camera_csv, dataset_path = (workdir / name for name in _OUTPUTS[:5])
    for name in _OUTPUTS:
        outputs.live(workdir / name)
    limit = rig.task.torque_limit_nm
    with (
        SimRig(rig, truth_log=truth_log) as device,
        MotorLink("twin", torque_limit_nm=limit, serial=device.connect()) as link,
        SampleLog(motor_log, LOOP_LOG_COLUMNS, metadata={"rig": rig.to_dict()}) as log,
    ):
        controller = rig_babble_controller(duration_s, limit, seed, program=program)
        loop = run_control_loop(link, controller, duration_s, log=log, progress=progress)
    times, points, hub = truth_link_points(truth_log, rig.task.rod, rig.task.plant)
    camera = SyntheticCamera(effects=CameraEffects.rig(), seed=seed)
    render_video(video, camera, times, points, hub, 100.0, clock_offset_s, 0.0005, progress=progress)
    track_video(video, camera_csv, progress=progress)
    notes = "digital twin: emulated serial link + synthetic camera"
    dataset, sync = build_rig_dataset(
        motor_log, camera_csv, dataset_path, rig.task.rod, trial_length_s=trial_length_s, notes=notes
    )
    for name in _OUTPUTS:
        outputs.done(workdir / name)
    paths = (motor_log, truth_log, video, camera_csv, dataset_path)
    return TwinSession(workdir, *paths, loop, sync, dataset, clock_offset_s, device.stats())


#: Every file :func:`run_twin_session` writes in its folder (besides the marker).
_OUTPUTS = tuple(
    "motor_log.csv truth_log.csv camera.avi camera.csv rig_dataset.npz camera.avi.json emulator_stats.json".split()
)


def compare_with_simulator_model(
    rig_dataset, seed: int = 0, n_test_trials: int = 6, history: int = 2, max_epochs: int = 150, plant: str = "prb"
) -> dict[str, object]:
    """Rollout errors at 1 s on held-out simulator trials of a model fitted on the twin's dataset and one on like
    simulator babbling: ``tip_rmse_m_twin``, ``tip_rmse_m_sim``, ``ratio``, ``errors_twin``, ``errors_sim``."""
    import torch

    from softpend.sysid import BabbleProtocol, babble
    from softpend.sysid.metrics import rollout_errors
    from softpend.sysid.training import fit_dynamics_model

    torch.set_num_threads(1)
    trial_length_s = rig_dataset.n_samples * rig_dataset.dt_s
    size: dict[str, Any] = dict(n_trials=rig_dataset.n_trials, trial_length_s=trial_length_s, dt_s=rig_dataset.dt_s)
    start: dict[str, Any] = dict(start="hanging", start_angle_std_rad=0.3, start_rate_std_rad_s=1.0)
    torques: dict[str, Any] = dict(feedback_trial_fraction=0.0, torque_std_fraction=0.5, torque_bandwidth_hz=2.0)
    protocol = BabbleProtocol(**size, **start, **torques)  # the twin's torque process (rig_babble_controller)
    common: dict[str, Any] = dict(params=rig_dataset.params or RodParams(), progress=False, plant=plant)
    sim_train = babble(protocol, seed=seed + 1000, **common)
    test_protocol = protocol.replace(n_trials=n_test_trials, trial_length_s=max(trial_length_s, 2.0))
    sim_test = babble(test_protocol, seed=seed + 2000, **common)
    settings: dict[str, Any] = dict(
        information="limited", history=history, max_epochs=max_epochs, patience=20, seed=seed
    )
    errors = {
        name: rollout_errors(fit_dynamics_model(data, **settings, progress=False).model, sim_test, horizon_s=1.0)
        for name, data in (("twin", rig_dataset), ("sim", sim_train))
    }
    twin, sim = (errors[name].at(1.0)["tip_rmse_m"] for name in ("twin", "sim"))
    out: dict[str, object] = {"tip_rmse_m_twin": twin, "tip_rmse_m_sim": sim, "ratio": twin / sim}
    return out | {f"errors_{name}": value for name, value in errors.items()}

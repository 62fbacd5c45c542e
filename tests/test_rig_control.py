"""Closed loop on the digital twin in simulated time: the emulated device behind the real protocol bytes and
driver, the synthetic camera filming it, the state estimator, a controller, the crash-safe logs -- the safe
stops, and runs that repeat bit for bit.  One smoke test drives a short closed loop through a real
pseudo-terminal (the emulator in its own process, the wall clock) and checks behaviour only.

The rod's true motion is read from the emulator's truth log."""

from __future__ import annotations

import json

import numpy as np
import pytest

from softpend.cli import main
from softpend.control.lqr import LQRController
from softpend.hardware.closed_loop import STATUS_CODES, TwinCamera, run_twin_control
from softpend.hardware.emulator import RigConfig
from softpend.hardware.estimator import EstimatorConfig
from softpend.io.samplelog import read_sample_log
from softpend.task import Task
from softpend.vision.camera import CameraModel
from softpend.vision.tip_source import CameraFaults

SMALL = CameraModel(width_px=320, height_px=240, px_per_m=320.0, centre_px=(160.0, 119.0))
TASK = Task(start_noise_rad=0.0)
UPRIGHT = RigConfig(task=TASK, initial_tilt_rad=0.1, hold_until_commanded=True)


def true_theta(truth_log, task: Task = TASK) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Device time [s], true tip angle [rad] and applied torque [N m] from a truth log."""
    log = read_sample_log(truth_log)
    plant = task.make_plant()
    n = plant.n_coordinates
    q = np.column_stack([log[f"q{i}_rad"] for i in range(n)])
    theta = np.array([plant.observation_from_state(row, np.zeros(n)).theta_rad for row in q])
    return log["device_time_s"], theta, log["applied_torque_nm"]


def test_lqr_holds_the_rod_on_the_twin_with_the_camera_in_the_loop(tmp_path, capsys):
    out = tmp_path / "run"
    assert (
        main(
            [
                "rig",
                "control",
                "lqr",
                "--twin",
                "--start",
                "upright",
                "--tilt",
                "0.1",
                "--duration",
                "3",
                "--start-noise",
                "0",
                "--max-blind-ms",
                "600",
                "--out",
                str(out),
                "--no-progress",
                "--seed",
                "3",
            ]
        )
        == 0
    )
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["stop_reason"] is None
    assert summary["camera"]["frames_tracked"] >= 175  # 60 frames/s for 3 s, in simulated time: none skipped
    assert summary["estimator"]["tips_accepted"] >= 0.9 * (summary["camera"]["frames_tracked"] - 5)
    assert summary["truth"]["success"] and summary["truth"]["upright_std_rad"] < 0.1
    time_s, theta, torque = true_theta(out / "truth_log.csv")
    assert np.max(np.abs(theta)) < 0.3
    motor = read_sample_log(out / "motor_log.csv")
    assert len(motor) == summary["samples"] and motor["time_s"][-1] >= 3.0
    assert motor["status"][-1] == STATUS_CODES["completed"]
    assert summary["armed_at_s"] < 0.5 and motor["commanded"][motor["time_s"] < summary["armed_at_s"]].sum() == 0
    # the estimate the controller saw follows the true tip angle (device clocks agree: the emulator's)
    true_at = np.interp(motor["device_time_s"] + motor["est_time_s"] - motor["time_s"], time_s, theta)
    error = motor["est_theta_rad"] - true_at
    assert np.sqrt(np.nanmean(error**2)) < 0.01, np.nanmax(np.abs(error))
    camera = read_sample_log(out / "camera_log.csv")
    assert camera["accepted"].sum() == summary["estimator"]["tips_accepted"]
    assert np.all(camera["delivered_host_time_s"] - camera["capture_host_time_s"] >= 0.02)
    assert torque[-1] == 0.0  # STOP at the end
    assert "success True" in capsys.readouterr().out


def test_camera_lost_then_stalled_is_bridged_then_a_safe_stop(tmp_path):
    controller = LQRController.from_params(TASK.rod, TASK.dt_s)
    camera = TwinCamera(
        fps=60, latency_s=0.02, model=SMALL, faults=CameraFaults(occlusions_s=((1.0, 1.25),), stall_after_s=2.0)
    )
    run = run_twin_control(
        controller, tmp_path, 5.0, rig=UPRIGHT, camera=camera, estimator_config=EstimatorConfig(max_blind_s=0.5)
    )
    result = run.result
    assert result.status == "camera_blind" and "no camera correction" in result.stop_reason
    assert result.camera["frames_lost"] >= 2  # the occlusion: lost frames, bridged without a stop
    motor = read_sample_log(run.motor_log)
    assert len(motor) == result.samples  # every sample processed is in the log
    assert motor["status"][-1] == STATUS_CODES["camera_blind"] and motor["command_torque_nm"][-1] == 0.0
    assert np.all(motor["status"][:-1] != STATUS_CODES["camera_blind"])
    camera_log = read_sample_log(run.camera_log)
    lost_at = camera_log["capture_device_time_s"][camera_log["lost"] > 0]  # loop time of the occlusion
    assert lost_at.max() - lost_at.min() > 0.1
    occluded = (motor["time_s"] > lost_at.max()) & (motor["time_s"] < lost_at.max() + 0.05)
    assert motor["blind_s"][occluded].max() > 0.1  # the loop ran on without camera corrections
    assert np.all(motor["status"][motor["time_s"] < lost_at.max() + 0.1] != STATUS_CODES["camera_blind"])
    stop_s = motor["time_s"][-1]
    last_frame = camera_log["capture_device_time_s"][-1]
    assert stop_s - last_frame >= 0.5 and stop_s < 4.5  # the stall at 2 s camera time, then max_blind_s
    time_s, theta, torque = true_theta(run.truth_log)
    start = motor["device_time_s"][0]
    bridged = (time_s > start + 0.5) & (time_s <= start + lost_at.max() + 0.2)
    assert np.max(np.abs(theta[bridged])) < 0.3, result.summary()  # held through the occlusion
    after = time_s > motor["device_time_s"][-1] + 0.05
    assert after.any() and np.all(torque[after] == 0.0)  # STOP in force
    assert json.loads((tmp_path / "summary.json").read_text())["result"]["status"] == "camera_blind"


class Exploding:
    """Holds the rod with an LQR, then raises."""

    def __init__(self) -> None:
        self.lqr = LQRController.from_params(TASK.rod, TASK.dt_s)
        self.calls = 0

    def reset(self) -> None:
        self.calls = 0

    def __call__(self, observation, q, q_dot, time_s):
        self.calls += 1
        if time_s > 0.5:
            raise RuntimeError("controller bug")
        return self.lqr(observation, q, q_dot, time_s)


def test_a_controller_that_raises_stops_the_motor_and_its_sample_is_logged(tmp_path):
    controller = Exploding()
    with pytest.raises(RuntimeError, match="controller bug"):
        run_twin_control(controller, tmp_path, 3.0, rig=UPRIGHT, camera=None)
    motor = read_sample_log(tmp_path / "motor_log.csv")
    assert motor["commanded"].sum() == controller.calls - 1  # every command but the one that raised
    assert motor["status"][-1] == STATUS_CODES["error"] and motor["command_torque_nm"][-1] == 0.0
    assert np.all(motor["status"][:-1] == STATUS_CODES["running"])
    assert 0.5 < motor["est_time_s"][-1] < 0.6
    time_s, theta, torque = true_theta(tmp_path / "truth_log.csv")
    after = time_s > motor["device_time_s"][-1] + 0.05
    assert after.any() and np.all(torque[after] == 0.0)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert "controller bug" in summary["error"]


def test_rig_control_command_checks_its_arguments(tmp_path):
    out = str(tmp_path / "x")
    assert main(["rig", "control", "lqr", "--out", out]) == 2  # neither --twin nor --port
    assert main(["rig", "control", "lqr", "--port", "/dev/null", "--out", out]) == 2  # no camera choice
    assert main(["rig", "control", "nonsense", "--twin", "--out", out]) == 2
    assert main(["rig", "control", "lqr", "--twin", "--camera", "0", "--out", out]) == 2
    assert main(["rig", "control", "lqr", "--twin", "--duration", "-1", "--out", out]) == 2
    assert main(["rig", "control", "lqr", "--twin", "--camera-effects", "foggy", "--out", out]) == 2


def test_run_folders_become_rig_controllers(tmp_path):
    from softpend.commands.rig_control import build_controller
    from softpend.pilco import GPSettings, OptimiserSettings, PilcoConfig, PolicySettings, run_pilco
    from softpend.rl.config import DQNConfig
    from softpend.rl.dqn import train_dqn

    train_dqn(
        DQNConfig(
            learning_starts=21,
            episode_s=1.0,
            eval_every_episodes=2,
            checkpoint_every_episodes=2,
            eval_seeds=(0,),
            eval_duration_s=1.5,
        ),
        seed=0,
        episodes=1,
        run_dir=tmp_path / "dqn",
        progress=False,
    )
    run_pilco(
        PilcoConfig(
            state="tip",
            control_dt_s=0.1,
            horizon_s=1.0,
            prediction_s=None,
            n_policy_trials=0,
            policy=PolicySettings(n_basis=5),
            gp=GPSettings(max_points=15, iterations=15),
            optimiser=OptimiserSettings(iterations=4),
            eval_seeds=(1000,),
            eval_duration_s=1.0,
            seed=3,
        ),
        progress=False,
    ).save(tmp_path / "pilco")
    plant = TASK.make_plant()
    q, q_dot = plant.hanging_state()
    observation = plant.observation_from_state(q, q_dot)
    for name, kind in (("dqn", "DQN"), ("pilco", "PILCO"), ("swingup", "energy swing-up")):
        controller, task, label = build_controller(str(tmp_path / name) if name != "swingup" else name, TASK)
        assert label.startswith(kind) and task.rod.n_links == TASK.rod.n_links
        controller.reset()
        torque = controller(observation, q, q_dot, 0.0)
        assert np.isfinite(torque) and abs(torque) <= TASK.torque_limit_nm + 1e-12


def test_two_twin_runs_of_the_same_start_and_seed_give_identical_logs_and_swing_up(tmp_path):
    """Simulated time: the same start and seeds give byte-identical motor, camera and truth logs; and the
    closed loop (energy swing-up, then LQR, behind the estimator and the camera) brings the rod up and holds it."""
    from softpend.control.swingup import EnergySwingUpController
    from softpend.study.rig_runs import run_truth_metrics

    task = Task(start_noise_rad=0.05)
    runs = [
        run_twin_control(
            EnergySwingUpController(task.rod, dt_s=task.dt_s),
            tmp_path / f"run{i}",
            6.0,
            rig=RigConfig(task=task, seed=7),
            camera=TwinCamera(seed=7, model=SMALL),
        )
        for i in range(2)
    ]
    for name in ("motor_log", "camera_log", "truth_log"):
        first, second = (getattr(run, name).read_bytes() for run in runs)
        assert first == second and len(first) > 10_000, name
    assert runs[0].result.summary() == runs[1].result.summary()
    other = run_twin_control(
        EnergySwingUpController(task.rod, dt_s=task.dt_s),
        tmp_path / "other",
        1.0,
        rig=RigConfig(task=task, seed=8),
        camera=TwinCamera(seed=8, model=SMALL),
    )
    assert other.truth_log.read_bytes()[:20_000] != runs[0].truth_log.read_bytes()[:20_000]  # the seed matters
    metrics = run_truth_metrics(runs[0].motor_log, runs[0].truth_log, task)
    assert metrics["success"] and metrics["swing_up_time_s"] < 4.0 and metrics["upright_std_rad"] < 0.05, metrics
    time_s, theta, torque = true_theta(runs[0].truth_log, task)
    assert np.all(np.abs(theta[time_s > time_s[-1] - 1.0]) < 0.15)  # upright at the end
    assert np.max(np.abs(torque)) <= task.torque_limit_nm and torque[-1] == 0.0  # the limit; STOP at the end


@pytest.mark.realtime
def test_a_short_closed_loop_through_a_pseudo_terminal_completes_and_stops_the_motor(tmp_path):
    """The real I/O path on the wall clock: the emulator in its own process, the driver on its pty, the closed
    loop (LQR holding the rod, encoder and model only).  Behaviour only, no timing figure."""
    import time

    from softpend.hardware.closed_loop import run_closed_loop
    from softpend.hardware.driver import MotorLink
    from softpend.hardware.emulator import EmulatorProcess
    from softpend.hardware.estimator import RigStateEstimator

    with EmulatorProcess(UPRIGHT, truth_log=tmp_path / "truth.csv") as emulator:
        with MotorLink(emulator.port, torque_limit_nm=TASK.torque_limit_nm, timeout_s=2.0) as link:
            result = run_closed_loop(link, LQRController.from_params(TASK.rod, TASK.dt_s), RigStateEstimator(TASK), 1.0)
        deadline = time.monotonic() + 10.0  # the STOP reaches the device, which logs the ticks after it
        while time.monotonic() < deadline and read_sample_log(tmp_path / "truth.csv")["applied_torque_nm"][-1] != 0:
            time.sleep(0.05)
        emulator.terminate()
    assert result.status == "completed" and result.stop_reason is None and result.samples >= 50
    log = read_sample_log(tmp_path / "truth.csv")
    assert np.any(log["applied_torque_nm"] != 0.0) and log["applied_torque_nm"][-1] == 0.0
    assert np.max(np.abs(log["applied_torque_nm"])) <= TASK.torque_limit_nm

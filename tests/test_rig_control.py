"""Closed loop through a real pseudo-terminal: the emulator in its own process, the synthetic camera filming
its live state, the state estimator, a controller, the crash-safe logs -- and the safe stops.

The rod's true motion is read from the emulator's truth log.  Nothing asserts tight timing (the CI machine
is shared): bounds are on angles, on what is logged, and on the torque in force after a stop."""

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

#: Real-time runs (the twin's emulator, camera or link timing): `make test` runs these on their own, after the rest.
pytestmark = pytest.mark.realtime

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


def test_lqr_holds_the_rod_through_the_pty_with_the_camera_in_the_loop(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["rig", "control", "lqr", "--twin", "--start", "upright", "--tilt", "0.1", "--duration", "3",
                 "--start-noise", "0", "--max-blind-ms", "600", "--out", str(out), "--no-progress", "--seed", "3"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "completed" and summary["stop_reason"] is None
    assert summary["camera"]["frames_tracked"] >= 60  # 60 frames/s for 3 s; fewer on a loaded machine
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
    assert np.sqrt(np.nanmean(error ** 2)) < 0.01, np.nanmax(np.abs(error))
    camera = read_sample_log(out / "camera_log.csv")
    assert camera["accepted"].sum() == summary["estimator"]["tips_accepted"]
    assert np.all(camera["delivered_host_time_s"] - camera["capture_host_time_s"] >= 0.02)
    assert torque[-1] == 0.0  # STOP at the end
    assert "success True" in capsys.readouterr().out


def test_camera_lost_then_stalled_is_bridged_then_a_safe_stop(tmp_path):
    controller = LQRController.from_params(TASK.rod, TASK.dt_s)
    camera = TwinCamera(fps=60, latency_s=0.02, model=SMALL,
                        faults=CameraFaults(occlusions_s=((1.0, 1.25),), stall_after_s=2.0))
    run = run_twin_control(controller, tmp_path, 5.0, rig=UPRIGHT, camera=camera,
                           estimator_config=EstimatorConfig(max_blind_s=0.5))
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
    from softpend.pilco import PilcoConfig, run_pilco
    from softpend.rl.config import DQNConfig
    from softpend.rl.dqn import train_dqn

    train_dqn(DQNConfig(learning_starts=21, episode_s=1.0, eval_every_episodes=2, checkpoint_every_episodes=2,
                        eval_seeds=(0,), eval_duration_s=1.5), seed=0, episodes=1, run_dir=tmp_path / "dqn",
              progress=False)
    run_pilco(PilcoConfig(state="tip", control_dt_s=0.1, horizon_s=1.0, prediction_s=None, n_policy_trials=0, n_basis=5,
                          max_gp_points=15, gp_iterations=15, policy_iterations=4, eval_seeds=(1000,),
                          eval_duration_s=1.0, seed=3), progress=False).save(tmp_path / "pilco")
    plant = TASK.make_plant()
    q, q_dot = plant.hanging_state()
    observation = plant.observation_from_state(q, q_dot)
    for name, kind in (("dqn", "DQN"), ("pilco", "PILCO"), ("swingup", "energy swing-up")):
        controller, task, label = build_controller(str(tmp_path / name) if name != "swingup" else name, TASK)
        assert label.startswith(kind) and task.rod.n_links == TASK.rod.n_links
        controller.reset()
        torque = controller(observation, q, q_dot, 0.0)
        assert np.isfinite(torque) and abs(torque) <= TASK.torque_limit_nm + 1e-12


def test_camera_process_delivers_frames_and_reports_its_end(tmp_path):
    """The twin's camera in its own process: frames arrive stamped on the host clock; its camera thread runs
    under real-time scheduling where the OS grants it, its main thread does not; a killed camera delivers
    nothing more and says it is no longer running; bad settings fail at start with the child's error."""
    import os
    import signal
    import time

    from softpend.hardware.camera_process import CameraProcess, camera_settings
    from softpend.hardware.emulator import start_emulator_process
    from softpend.hardware.realtime import CAMERA_PRIORITY, realtime_priority

    with realtime_priority(CAMERA_PRIORITY) as granted:  # whether the OS grants it to this user
        pass

    with start_emulator_process(UPRIGHT, scene=True) as emulator:
        camera = CameraProcess(emulator.take_scene_fd(), TASK, camera_settings(60.0, 0.02, model=SMALL))
        try:
            deadline = time.monotonic() + 10.0
            frames = []
            while len(frames) < 10 and time.monotonic() < deadline:
                frames += camera.poll()
                time.sleep(0.01)
            assert len(frames) >= 10 and camera.running
            assert all(m.delivered_time_s - m.capture_time_s >= 0.02 for m in frames)
            assert all(m.delivered_time_s <= time.monotonic() for m in frames)
            assert [m.frame for m in frames] == sorted(m.frame for m in frames)
            assert not any(m.lost for m in frames[1:])
            pid = camera.process.pid
            policies = {int(tid): os.sched_getscheduler(int(tid)) for tid in os.listdir(f"/proc/{pid}/task")}
            realtime = [tid for tid, policy in policies.items() if policy == os.SCHED_FIFO]
            assert policies[pid] == os.SCHED_OTHER and bool(realtime) == granted, policies
            assert all(os.sched_getparam(tid).sched_priority == CAMERA_PRIORITY for tid in realtime)
            camera.process.send_signal(signal.SIGKILL)
            camera.process.wait(5.0)
            camera.poll()
            assert not camera.running and camera.poll() == []
        finally:
            camera.close()
        assert camera.stats()["frames_tracked"] >= 10
    with start_emulator_process(UPRIGHT, scene=True) as emulator:
        with pytest.raises(RuntimeError, match="fps"):
            CameraProcess(emulator.take_scene_fd(), TASK, camera_settings(-5.0, 0.02))

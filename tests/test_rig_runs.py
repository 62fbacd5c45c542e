"""Controllers on the twin beside the ideal simulator (softpend.study.rig_runs): the scoring from the logs, the
rows of failed runs, the summary with its Wilson intervals, and the same start in both."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softpend.control.lqr import LQRController
from softpend.hardware.closed_loop import rig_control_columns
from softpend.hardware.emulator import RigConfig, SimRig, truth_columns
from softpend.io.samplelog import SampleLog, read_sample_log
from softpend.stats import wilson_interval
from softpend.study.presets import REPORT_SEEDS
from softpend.study.rig_runs import (
    JOINT_SWINGUP,
    OBSERVATION_SWINGUP,
    SIMULATOR,
    FrameKeeper,
    RigCondition,
    rig_controllers,
    run_truth_metrics,
    simulator_starts,
    summary_rows,
    text_figures,
    torque_total_variation_per_s,
    truth_metrics,
    twin_start,
)
from softpend.task import Task
from softpend.vision.camera import CameraModel
from softpend.vision.tip_source import CameraFaults

TASK = Task(start_noise_rad=0.05)


def test_torque_chatter_is_the_total_variation_per_second():
    assert torque_total_variation_per_s([0.0, 1.0, 2.0, 3.0], [0.0, 1.0, -1.0, -1.0]) == pytest.approx(1.0)
    assert math.isnan(torque_total_variation_per_s([0.0], [0.5]))


def _truth_log(path, task: Task, hang_until_s: float, end_s: float, dt_s: float = 0.01):
    """A truth log of a rod hanging until ``hang_until_s``, then straight up at rest."""
    n = task.make_plant().n_coordinates
    with SampleLog(path, truth_columns(n)) as log:
        for k in range(int(round(end_s / dt_s)) + 1):
            t = k * dt_s
            q = np.zeros(n)
            if t < hang_until_s:
                q[0] = math.pi
            log.append([t, 0.01, *q, *np.zeros(n)])
    return path


def test_truth_metrics_score_only_the_window_the_controller_was_in_charge(tmp_path):
    path = _truth_log(tmp_path / "truth.csv", TASK, hang_until_s=1.0, end_s=4.0)
    whole = truth_metrics(path, TASK, success_std_rad=0.1)
    assert whole["swing_up_time_s"] == pytest.approx(1.0) and whole["success"]
    late = truth_metrics(path, TASK, success_std_rad=0.1, start_time_s=0.5)
    assert late["swing_up_time_s"] == pytest.approx(0.5)
    # the window ends before the rod has been upright for the hold time: no swing-up
    short = truth_metrics(path, TASK, success_std_rad=0.1, start_time_s=0.5, end_time_s=1.5)
    assert math.isinf(short["swing_up_time_s"]) and not short["success"]
    assert truth_metrics(path, TASK, start_time_s=3.99) == {}


def test_a_run_is_scored_from_its_first_command_to_its_last_sample_not_on_the_fall_after_the_stop(tmp_path):
    n = TASK.make_plant().n_coordinates
    truth = tmp_path / "truth.csv"
    with SampleLog(truth, truth_columns(n)) as log:  # upright at rest until 3 s, then the unheld rod hangs
        for k in range(501):
            q = np.zeros(n)
            q[0] = 0.0 if k * 0.01 <= 3.0 else math.pi
            log.append([k * 0.01, 0.0, *q, *np.zeros(n)])
    motor = tmp_path / "motor.csv"
    columns = rig_control_columns(n)
    with SampleLog(motor, columns) as log:  # armed at 0.5 s, last sample at 3 s
        for k in range(301):
            row = dict.fromkeys(columns, 0.0)
            row.update(device_time_s=k * 0.01, time_s=k * 0.01, commanded=float(k >= 50))
            log.append([row[c] for c in columns])
    scored = run_truth_metrics(motor, truth, TASK, success_std_rad=0.1)
    assert scored["success"] and scored["upright_std_rad"] < 1e-9
    assert truth_metrics(truth, TASK, success_std_rad=0.1)["upright_std_rad"] > 1.0  # the whole log holds the fall
    with SampleLog(tmp_path / "idle.csv", columns) as log:  # a controller that never commanded scores nothing
        log.append([0.0] * len(columns))
    assert run_truth_metrics(tmp_path / "idle.csv", truth, TASK) == {}


def test_a_start_seeded_s_begins_from_the_same_state_on_the_twin_and_in_the_simulator():
    from softpend.envs import SoftPendulumEnv

    for seed in REPORT_SEEDS[:3]:
        env = SoftPendulumEnv(**TASK.env_kwargs())
        env.reset(seed=seed)
        q_sim, qd_sim = env.unwrapped.plant.joint_state()
        q_twin, qd_twin = SimRig(RigConfig(task=TASK, seed=seed)).plant.joint_state()
        np.testing.assert_array_equal(q_sim, q_twin)
        np.testing.assert_array_equal(qd_sim, qd_twin)


def test_simulator_rows_score_the_swing_up_and_a_motor_left_off():
    controllers = rig_controllers(TASK)
    assert list(controllers) == [OBSERVATION_SWINGUP, JOINT_SWINGUP]
    assert list(rig_controllers(Task(plant="beam"))) == [OBSERVATION_SWINGUP]  # no PRB joint state on the beam
    rows = simulator_starts(controllers[JOINT_SWINGUP](), JOINT_SWINGUP, TASK, REPORT_SEEDS[:1], 6.0)
    (row,) = rows
    assert row["condition"] == SIMULATOR and row["seed"] == REPORT_SEEDS[0]
    assert row["success"] and row["swing_up_time_s"] < 5.0 and row["upright_std_rad"] <= 0.1
    assert row["peak_torque_nm"] == pytest.approx(TASK.torque_limit_nm) and row["torque_chatter_nm_per_s"] > 0
    assert row["stop"] == ""

    class Off:
        def reset(self):
            pass

        def __call__(self, observation, q, q_dot, time_s):
            return 0.0

    (off,) = simulator_starts(Off(), "off", TASK, REPORT_SEEDS[:1], 2.0)
    assert not off["success"] and math.isinf(off["swing_up_time_s"]) and off["upright_std_rad"] > 3.0
    assert off["peak_torque_nm"] == 0.0 and off["torque_chatter_nm_per_s"] == 0.0


def _row(condition, controller, success, swing_up_s=2.0, std=0.05, peak=0.06, chatter=1.0, stop=""):
    return {
        "condition": condition,
        "controller": controller,
        "seed": 0,
        "success": success,
        "swing_up_time_s": swing_up_s,
        "upright_std_rad": std,
        "peak_torque_nm": peak,
        "torque_chatter_nm_per_s": chatter,
        "stop": stop,
    }


def test_summary_rows_count_successes_with_wilson_intervals_in_order_of_appearance():
    rows = [
        _row("nominal twin", "a", True, 2.0, 0.03),
        _row("nominal twin", "a", True, 3.0, 0.08),
        _row("nominal twin", "a", False, math.inf, 1.5, chatter=math.nan, stop="camera blind: ..."),
        _row(SIMULATOR, "a", True, 1.0, 0.01, peak=0.05),
        _row(SIMULATOR, "b", False, math.inf, 2.0),
    ]
    summary = summary_rows(rows)
    assert [(r["condition"], r["controller"]) for r in summary] == [
        ("nominal twin", "a"),
        (SIMULATOR, "a"),
        (SIMULATOR, "b"),
    ]
    twin = summary[0]
    assert (twin["starts"], twin["successes"], twin["stops"]) == (3, 2, 1)
    assert (twin["success_low"], twin["success_high"]) == pytest.approx(wilson_interval(2, 3))
    assert twin["swing_up_time_s"] == pytest.approx(2.5)  # median over the successes only
    assert twin["upright_std_rad"] == pytest.approx(0.08)  # the worst success, not the failure
    assert twin["torque_chatter_nm_per_s"] == pytest.approx(1.0)  # NaN left out
    failed = summary[2]
    assert failed["successes"] == 0 and math.isnan(failed["swing_up_time_s"]) and math.isnan(failed["upright_std_rad"])
    text = text_figures(summary, {"a": "a", "b": "b"}, {"sim": SIMULATOR, "nominal": "nominal twin"})
    assert text["a_nominal_success"] == "2 of 3" and text["a_nominal_stops"] == "1"
    assert text["a_nominal_interval"] == f"{twin['success_low']:.2f} to {twin['success_high']:.2f}"
    assert text["b_sim_swing_up_s"] == "none" and text["b_nominal_success"] == "not run"


def test_rig_condition_checks_its_arguments():
    with pytest.raises(ValueError, match="fps"):
        RigCondition("x", fps=0.0)
    with pytest.raises(ValueError, match="faults"):
        RigCondition("x", faults="stall")
    condition = RigCondition("x", fps=30.0, camera_latency_s=0.04, counts_per_rev=1024)
    assert condition.camera(7).fps == 30.0 and condition.camera(7).seed == 7
    assert condition.rig(TASK, 7).counts_per_rev == 1024 and condition.estimator().counts_per_rev == 1024


SMALL = CameraModel(width_px=320, height_px=240, px_per_m=320.0, centre_px=(160.0, 119.0))


class Camera(RigCondition):
    """A condition with the small camera of the closed-loop tests (cheaper frames)."""

    def camera(self, seed):
        import dataclasses

        return dataclasses.replace(super().camera(seed), model=SMALL)


def test_a_stalled_camera_becomes_a_failed_row_and_a_raising_controller_raises(tmp_path):
    lqr = LQRController.from_params(TASK.rod, TASK.dt_s)
    condition = Camera("stalling camera", faults=CameraFaults(stall_after_s=0.6), max_blind_s=0.3)
    keeper = FrameKeeper(every=5)
    row = twin_start(lqr, "LQR", TASK, condition, REPORT_SEEDS[0], 3.0, tmp_path / "stall", on_frame=keeper)
    assert not row["success"] and row["stop"].startswith("camera blind: no camera correction")
    assert row["condition"] == "stalling camera" and row["frames_tracked"] >= 5
    assert math.isfinite(row["upright_std_rad"]) and row["upright_std_rad"] > 2.0  # the hanging rod, scored
    motor = read_sample_log(tmp_path / "stall" / "motor_log.csv")
    assert motor["time_s"][-1] < 2.0  # stopped long before the run's end
    frames = keeper.at_loop_times(tmp_path / "stall" / "camera_log.csv")
    assert frames and len(frames) <= len(keeper.frames)
    times = [t for t, _, _ in frames]
    assert times == sorted(times) and times[-1] < motor["time_s"][-1]
    assert frames[0][1].shape == (SMALL.height_px, SMALL.width_px, 3)

    class Broken:
        def reset(self):
            pass

        def __call__(self, observation, q, q_dot, time_s):
            if time_s > 0.2:
                raise RuntimeError("controller bug")
            return 0.0

    with pytest.raises(RuntimeError, match="controller bug"):
        twin_start(Broken(), "broken", TASK, Camera("nominal"), REPORT_SEEDS[0], 2.0, tmp_path / "broken")

"""The MPPI planner learned in simulation as a rig controller on the digital twin (camera and estimator in the
loop), with tiny planner settings: its torque stays within the limit and its calls' wall time is reported."""

from __future__ import annotations

import json
import math

import pytest

from softpend.cli import main
from softpend.commands.rig_control import build_controller
from softpend.hardware.closed_loop import run_twin_control
from softpend.hardware.emulator import RigConfig
from softpend.io.samplelog import read_sample_log
from softpend.study import data_efficiency
from softpend.study.rig_runs import TimedController, planner_twin_figures, step_time_figures
from softpend.task import Task

TINY = dict(
    identify_windows=0,
    excitation_s=0.5,
    trial_s=0.3,
    hold_s=0.2,
    max_trials=1,
    ensemble_size=2,
    hidden_width=8,
    train_steps=5,
    horizon_s=0.15,
    n_samples=4,
)
TASK = Task()


def test_the_planner_runs_on_the_twin_within_the_torque_limit(tmp_path):
    controller, task, label = build_controller("planner", TASK, planner_overrides=TINY)
    assert isinstance(controller, TimedController) and controller.info["planner_plant_s"] > 0.5
    assert "plant s" in label
    torques = []

    class Recording(TimedController):
        def __call__(self, *args):
            torques.append(super().__call__(*args))
            return torques[-1]

    recording = Recording(controller.controller)
    run = run_twin_control(recording, tmp_path, 1.0, rig=RigConfig(task=task, seed=3))
    assert run.result.stop_reason is None
    limit = task.torque_limit_nm
    assert len(torques) == len(recording.step_ms) > 20
    assert max(abs(t) for t in torques) <= limit
    log = read_sample_log(run.motor_log)
    assert abs(log["command_torque_nm"]).max() <= limit and abs(log["applied_torque_nm"]).max() <= limit
    figures = step_time_figures(recording.step_ms, task.dt_s)
    assert figures["steps_timed"] == len(torques) and math.isfinite(figures["step_ms_p95"])
    assert 0.0 <= figures["steps_over_period"] <= 1.0
    assert figures["control_period_ms"] == pytest.approx(10.0)


def test_planner_twin_figures_count_fresh_starts_and_report_step_times():
    figures = planner_twin_figures((20_000,), duration_s=0.5, overrides=TINY)
    assert figures["starts"] == 1 and 0 <= figures["successes"] <= 1
    assert figures["steps_timed"] > 0 and math.isfinite(figures["step_ms_p95"])
    assert figures["control_period_ms"] == pytest.approx(1e3 * TASK.dt_s)
    assert figures["rows"][0]["peak_torque_nm"] <= TASK.torque_limit_nm + 1e-12
    with pytest.raises(ValueError, match="selection_seeds"):
        planner_twin_figures((1000,), duration_s=0.5, overrides=TINY)


def test_rig_control_planner_command_reports_plant_seconds_and_step_times(tmp_path, monkeypatch):
    original = data_efficiency.planner_config
    monkeypatch.setattr(data_efficiency, "planner_config", lambda task, overrides=None: original(task, TINY))
    out = tmp_path / "run"
    args = ["rig", "control", "planner", "--twin", "--duration", "0.5", "--no-progress", "--out", str(out)]
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["planner_plant_s"] > 0.5 and summary["steps_timed"] > 0
    assert math.isfinite(summary["step_ms_p95"]) and summary["control_period_ms"] == pytest.approx(10.0)
    assert summary["truth"]["peak_torque_nm"] <= TASK.torque_limit_nm + 1e-12

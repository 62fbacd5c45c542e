"""Figures of a closed-loop twin run from its logs: the rod's true motion and the torque chatter."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from softpend.evaluation import SUCCESS_STD_RAD, metrics_from_trajectory
from softpend.io.samplelog import read_sample_log
from softpend.task import Task


def truth_trajectory(
    truth_log: str | Path, task: Task, start_time_s: float = -math.inf, end_time_s: float = math.inf
) -> dict[str, np.ndarray]:
    """``time_s`` (device), ``theta_rad``, ``torque_nm`` and ``phi_dot_rad_s`` from the emulator's truth log, within
    the device-time window."""
    log, plant = read_sample_log(truth_log), task.make_plant()
    keep = (log["device_time_s"] >= start_time_s) & (log["device_time_s"] <= end_time_s)
    q, qd = (
        np.column_stack([log[f"q{i}{s}"][keep] for i in range(plant.n_coordinates)]) for s in ("_rad", "_dot_rad_s")
    )
    observations = [plant.observation_from_state(a, b) for a, b in zip(q, qd)]
    theta, rate = (np.array([getattr(o, name) for o in observations]) for name in ("theta_rad", "phi_dot_rad_s"))
    time_s, torque = log["device_time_s"][keep], log["applied_torque_nm"][keep]
    return {"time_s": time_s, "theta_rad": theta, "torque_nm": torque, "phi_dot_rad_s": rate}


def truth_metrics(
    truth_log: str | Path,
    task: Task,
    success_std_rad: float = SUCCESS_STD_RAD,
    start_time_s: float = -math.inf,
    end_time_s: float = math.inf,
) -> dict[str, float]:
    """The evaluation's metrics of the true motion in the window; empty for fewer than 3 ticks."""
    t = truth_trajectory(truth_log, task, start_time_s, end_time_s)
    if len(t["time_s"]) < 3:
        return {}
    metrics = metrics_from_trajectory(t["time_s"], t["theta_rad"], t["torque_nm"], t["phi_dot_rad_s"], success_std_rad)
    return {key: (value if isinstance(value, bool) else float(value)) for key, value in metrics.items()}


def run_truth_metrics(
    motor_log: str | Path, truth_log: str | Path, task: Task, success_std_rad: float = SUCCESS_STD_RAD
) -> dict[str, float]:
    """:func:`truth_metrics` from the first command to the motor log's last sample; empty when it never commanded."""
    motor = read_sample_log(motor_log)
    if not (commanded := motor["commanded"] > 0).any():
        return {}
    start_s, end_s = float(motor["device_time_s"][commanded][0]), float(motor["device_time_s"][-1])
    return truth_metrics(truth_log, task, success_std_rad, start_s, end_s)


def torque_chatter_nm_per_s(motor_log: str | Path) -> float:
    """:func:`torque_total_variation_per_s` of the commanded samples of a motor log."""
    log = read_sample_log(motor_log)
    commanded = log["commanded"] > 0
    return torque_total_variation_per_s(log["time_s"][commanded], log["command_torque_nm"][commanded])


def torque_total_variation_per_s(time_s: np.ndarray, torque_nm: np.ndarray) -> float:
    """``sum |tau[k+1] - tau[k]| / (t[-1] - t[0])`` [N m/s]; NaN for fewer than 2 samples or no elapsed time."""
    time_s, torque = np.asarray(time_s, dtype=float), np.asarray(torque_nm, dtype=float)
    if len(torque) < 2 or time_s[-1] <= time_s[0]:
        return float("nan")
    return float(np.sum(np.abs(np.diff(torque))) / (time_s[-1] - time_s[0]))

"""Figures of a closed-loop run on the digital twin, from its logs: what the rod truly did (the emulator's
truth log, scored by :func:`softpend.evaluation.metrics_from_trajectory`) and how hard the motor was driven
(torque chatter, from the motor log)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from softpend.evaluation import metrics_from_trajectory
from softpend.io.samplelog import read_sample_log
from softpend.task import Task

__all__ = ["torque_chatter_nm_per_s", "truth_metrics"]


def truth_metrics(truth_log: str | Path, task: Task, success_std_rad: float = 0.2) -> dict[str, float]:
    """Swing-up time, upright std, peak torque, energy and success of a twin run from the emulator's truth log
    (the rod's true state every tick; ``task`` is the emulator's).  Empty for a log of fewer than 3 ticks."""
    log = read_sample_log(truth_log)
    time_s = log["device_time_s"]
    if len(time_s) < 3:
        return {}
    plant = task.make_plant()
    n = plant.n_coordinates
    q = np.column_stack([log[f"q{i}_rad"] for i in range(n)])
    qd = np.column_stack([log[f"q{i}_dot_rad_s"] for i in range(n)])
    observations = [plant.observation_from_state(a, b) for a, b in zip(q, qd)]
    metrics = metrics_from_trajectory(time_s, np.array([o.theta_rad for o in observations]), log["applied_torque_nm"],
                                      np.array([o.phi_dot_rad_s for o in observations]),
                                      success_std_rad=success_std_rad)
    return {key: (value if isinstance(value, bool) else float(value)) for key, value in metrics.items()}


def torque_chatter_nm_per_s(motor_log: str | Path) -> float:
    """Total variation of the commanded torque per second of the run, ``sum |tau[k+1] - tau[k]| / T`` [N m/s],
    over the samples the controller commanded (a motor log of :func:`softpend.hardware.closed_loop.run_closed_loop`)."""
    log = read_sample_log(motor_log)
    commanded = log["commanded"] > 0
    torque = log["command_torque_nm"][commanded]
    time_s = log["time_s"][commanded]
    if len(torque) < 2 or time_s[-1] <= time_s[0]:
        return float("nan")
    return float(np.sum(np.abs(np.diff(torque))) / (time_s[-1] - time_s[0]))

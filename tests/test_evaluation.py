"""The shared evaluation: metrics on hand-made trajectories and a closed loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softpend.evaluation import FunctionController, evaluate_controller, metrics_from_trajectory
from softpend.task import Task


def _trajectory(theta: np.ndarray, dt: float = 0.01):
    t = np.arange(len(theta)) * dt
    return t, theta


def test_swing_up_time_is_first_time_theta_stays_inside_for_one_second() -> None:
    dt = 0.01
    theta = np.full(1001, 3.0)
    theta[200:250] = 0.1  # a brief pass through upright (0.5 s): not a swing-up
    theta[300:] = 0.05 * np.sin(np.arange(701) * 0.3)  # stays up from t = 3 s
    t, th = _trajectory(theta, dt)
    m = metrics_from_trajectory(t, th, np.zeros_like(t), np.zeros_like(t))
    assert m["swing_up_time_s"] == pytest.approx(3.0)
    assert m["upright_std_rad"] == pytest.approx(np.sqrt(np.mean(theta[300:] ** 2)))
    assert m["upright_mean_abs_rad"] == pytest.approx(np.mean(np.abs(theta[300:])))
    assert m["success"]


def test_never_swung_up_reports_inf_and_a_large_error() -> None:
    t, th = _trajectory(np.full(500, 2.0))
    m = metrics_from_trajectory(t, th, np.zeros_like(t), np.zeros_like(t))
    assert math.isinf(m["swing_up_time_s"]) and not m["success"]
    assert m["upright_std_rad"] == pytest.approx(2.0)


def test_swing_up_needs_the_full_second_before_the_end() -> None:
    theta = np.full(300, 3.0)
    theta[250:] = 0.0  # only 0.5 s upright at the end
    t, th = _trajectory(theta)
    assert math.isinf(metrics_from_trajectory(t, th, np.zeros(300), np.zeros(300))["swing_up_time_s"])


def test_peak_torque_and_energy() -> None:
    n = 101
    t = np.arange(n) * 0.01
    torque = np.full(n, -0.05)
    torque[10] = 0.06
    phi_dot = np.full(n, 2.0)
    m = metrics_from_trajectory(t, np.zeros(n), torque, phi_dot)
    assert m["peak_torque_nm"] == pytest.approx(0.06)
    assert m["energy_used_j"] == pytest.approx((99 * 0.05 + 0.06) * 2.0 * 0.01)


def test_metric_input_validation() -> None:
    with pytest.raises(ValueError, match="same length"):
        metrics_from_trajectory(np.arange(5), np.zeros(4), np.zeros(5), np.zeros(5))
    with pytest.raises(ValueError, match="theta_rad"):
        metrics_from_trajectory(np.arange(5.0), np.array([0, np.nan, 0, 0, 0]), np.zeros(5), np.zeros(5))


def test_closed_loop_hub_feedback_keeps_the_soft_rod_upright() -> None:
    # a PD loop on the hub angle: the rod is stiff enough to stand when its base is held
    controller = FunctionController(lambda o, q, qd, t: -0.5 * q[0] - 0.05 * qd[0])
    summary = evaluate_controller(controller, Task(start="upright"), seeds=[0, 1], duration_s=3.0)
    assert summary.success_rate == 1.0
    assert summary.median("upright_std_rad") < 0.1
    assert summary.results[0].observations.shape == (301, 10)
    # doing nothing from hanging never swings up
    idle = evaluate_controller(FunctionController(lambda o, q, qd, t: 0.0), seeds=[0], duration_s=2.0)
    assert idle.success_rate == 0.0 and math.isinf(idle.results[0].swing_up_time_s)


def test_evaluation_is_reproducible_per_seed() -> None:
    controller = FunctionController(lambda o, q, qd, t: 0.06 * math.copysign(1.0, o.phi_dot_rad_s))
    a = evaluate_controller(controller, seeds=[5], duration_s=1.0).results[0]
    b = evaluate_controller(controller, seeds=[5], duration_s=1.0).results[0]
    np.testing.assert_array_equal(a.observations, b.observations)


def test_non_finite_controller_output_is_an_error() -> None:
    with pytest.raises(ValueError, match="non-finite torque"):
        evaluate_controller(FunctionController(lambda o, q, qd, t: float("nan")), seeds=[0], duration_s=0.5)

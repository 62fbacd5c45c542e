"""PID on the tip angle: filtered derivative, anti-windup, closed loop on the true plant, tuning."""

import numpy as np
import pytest

from softpend.control.pid import PIDController, PIDGains, plant_simulator, tune_pid
from softpend.evaluation import evaluate_controller
from softpend.plant import RodParams
from softpend.task import Task


def test_filtered_derivative_of_a_step():
    pid = PIDController(PIDGains(0.0, 0.0, 1.0), dt_s=0.01, torque_limit_nm=100.0)
    pid.update(0.0)
    first = -pid.update(0.1)
    assert first == pytest.approx(0.1 / (0.02 + 0.01))
    second = -pid.update(0.1)
    assert second == pytest.approx(first * 0.02 / 0.03)


def test_anti_windup_bounds_the_integrator():
    pid = PIDController(PIDGains(0.1, 1.0, 0.0), torque_limit_nm=0.06)  # T_t = 10 dt = 0.1 s (K_d = 0)
    for _ in range(300):  # 3 s of a large constant error: the output saturates (the bare integral would reach 3)
        assert pid.update(1.0) == pytest.approx(-0.06)
    # back-calculation holds the integrator where u = limit + T_t K_i e: 0.06 + 0.1 - 0.1 = 0.06
    assert pid.integral_nm == pytest.approx(0.06, abs=1e-3)
    assert abs(pid.update(-0.3)) < 0.06  # when the error reverses, it leaves saturation at once


def test_wraps_the_tip_angle():
    pid = PIDController(PIDGains(1.0, 0.0, 0.0), torque_limit_nm=10.0)
    assert pid.update(2 * np.pi + 0.1) == pytest.approx(-0.1)


def test_pid_holds_the_true_plant_upright():
    params = RodParams()
    pid = PIDController(PIDGains(0.19, 0.0005, 0.014))
    q = np.zeros(params.n_links + 1)
    q[0] = 0.2
    result = evaluate_controller(
        pid, Task(start="upright"), seeds=(0,), duration_s=4.0, initial_state=(q, 0 * q)
    ).results[0]
    assert result.diverged is None
    assert result.swing_up_time_s < 1.0
    assert np.all(np.abs(result.theta_rad[-100:]) < 0.02)


def test_tuning_lowers_the_cost_on_a_tiny_budget():
    result = tune_pid(
        plant_simulator(), initial_gains=PIDGains(0.3, 0.1, 0.005), tilts_rad=(0.1,), duration_s=1.0, max_evaluations=6
    )
    assert result.cost < result.initial_cost
    assert result.n_evaluations <= 8


def test_bad_arguments():
    with pytest.raises(ValueError, match="kp_nm_per_rad"):
        PIDGains(-1.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="torque_limit_nm"):
        PIDController(PIDGains(1, 1, 1), torque_limit_nm=0.0)
    with pytest.raises(ValueError, match="theta_rad"):
        PIDController(PIDGains(1, 1, 1)).update(float("nan"))

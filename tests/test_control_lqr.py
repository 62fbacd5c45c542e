"""LQR: closed-loop stability of the designs, saturation, recovery on the true plant, region of attraction."""

import numpy as np
import pytest

from softpend.control.lqr import LQRController, design_lqr
from softpend.control.region import region_of_attraction_rad
from softpend.evaluation import evaluate_controller
from softpend.plant import Observation, RodParams
from softpend.task import Task

PARAMS = RodParams()


@pytest.fixture(scope="module")
def joint_lqr():
    return LQRController.from_params(PARAMS)


@pytest.fixture(scope="module")
def observation_lqr():
    return LQRController.from_params(PARAMS, state="observation")


def _tilt(angle):
    q = np.zeros(PARAMS.n_links + 1)
    q[0] = angle
    return q, np.zeros_like(q)


def test_closed_loop_eigenvalues_inside_unit_circle(joint_lqr, observation_lqr):
    for lqr in (joint_lqr, observation_lqr):
        assert np.max(np.abs(np.linalg.eigvals(lqr.model.a - lqr.model.b @ lqr.gain.reshape(1, -1)))) < 1.0
    assert np.max(np.abs(joint_lqr.model.eigenvalues())) > 1.05  # open loop is unstable


def test_continuous_design_left_half_plane():
    from softpend.control.linearise import linearise_exudyn

    model = linearise_exudyn(RodParams(n_links=1)).state_space()
    gain = design_lqr(model, np.eye(4), 1.0)
    assert np.all(np.linalg.eigvals(model.a - model.b @ gain).real < 0)
    assert np.any(model.eigenvalues().real > 0)  # open loop is not


def test_saturation(joint_lqr):
    n = PARAMS.n_links + 1
    obs = Observation(*np.zeros(10))
    big = joint_lqr(obs, np.full(n, 0.5), np.zeros(n), 0.0)
    assert abs(big) == pytest.approx(PARAMS.torque_limit_nm)
    q = np.zeros(n)
    q[0] = 1e-4
    small = joint_lqr(obs, q, np.zeros(n), 0.0)
    assert small == pytest.approx(-joint_lqr.gain[0, 0] * 1e-4)
    # a hub angle that went round once is wrapped back
    assert joint_lqr(obs, q + np.eye(n)[0] * 2 * np.pi, np.zeros(n), 0.0) == pytest.approx(small)


@pytest.mark.parametrize("which", ["joint", "observation"])
def test_recovers_from_tilt_and_stays_upright(which, joint_lqr, observation_lqr):
    controller = joint_lqr if which == "joint" else observation_lqr
    result = evaluate_controller(
        controller, Task(start="upright"), seeds=(0,), duration_s=4.0, initial_state=_tilt(0.2)
    ).results[0]
    assert result.diverged is None
    assert result.swing_up_time_s < 0.5
    assert result.upright_std_rad < 0.02
    assert np.all(np.abs(result.theta_rad[-200:]) < 1e-3)
    assert result.peak_torque_nm <= PARAMS.torque_limit_nm + 1e-12


def test_region_of_attraction_is_bounded_by_the_torque_limit(joint_lqr):
    roa = region_of_attraction_rad(joint_lqr, Task(rod=PARAMS), step_rad=0.1, resolution_rad=0.02, duration_s=3.0)
    static_bound = np.arcsin(PARAMS.torque_limit_nm / PARAMS.gravity_torque_horizontal_nm)
    assert 0.3 < roa.largest_recovered_rad <= static_bound + 0.02
    assert roa.smallest_failed_rad - roa.largest_recovered_rad <= 0.02 + 1e-9


def test_bad_arguments():
    with pytest.raises(ValueError, match="state"):
        LQRController.from_params(PARAMS, state="tip")
    with pytest.raises(ValueError, match="torque_limit_nm"):
        LQRController(np.zeros((1, 2)), lambda o, q, qd: np.zeros(2), torque_limit_nm=-1.0)

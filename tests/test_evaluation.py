"""The shared evaluation: metrics on hand-made trajectories and a closed loop."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softpend.envs import SoftPendulumDiscreteEnv
from softpend.evaluation import (
    BatchPolicy,
    evaluate,
    evaluate_controller,
    metrics_from_trajectory,
    run_episode,
)
from softpend.rl.training_env import HeldActionController
from softpend.task import Task


def as_controller(function):
    """A plain function ``f(observation, q, q_dot, time_s) -> torque_nm`` as a controller."""
    function.reset = lambda: None
    return function


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
    controller = as_controller(lambda o, q, qd, t: -0.5 * q[0] - 0.05 * qd[0])
    summary = evaluate_controller(controller, Task(start="upright"), seeds=[0, 1], duration_s=3.0)
    assert summary.success_rate == 1.0
    assert summary.median("upright_std_rad") < 0.1
    assert summary.results[0].observations.shape == (301, 10)
    # doing nothing from hanging never swings up
    idle = evaluate_controller(as_controller(lambda o, q, qd, t: 0.0), seeds=[0], duration_s=2.0)
    assert idle.success_rate == 0.0 and math.isinf(idle.results[0].swing_up_time_s)


def test_evaluation_is_reproducible_per_seed() -> None:
    controller = as_controller(lambda o, q, qd, t: 0.06 * math.copysign(1.0, o.phi_dot_rad_s))
    a = evaluate_controller(controller, seeds=[5], duration_s=1.0).results[0]
    b = evaluate_controller(controller, seeds=[5], duration_s=1.0).results[0]
    np.testing.assert_array_equal(a.observations, b.observations)


def test_non_finite_controller_output_is_an_error() -> None:
    with pytest.raises(ValueError, match="non-finite torque"):
        evaluate_controller(as_controller(lambda o, q, qd, t: float("nan")), seeds=[0], duration_s=0.5)


def test_an_evaluation_can_stop_at_its_first_failing_start_with_the_same_episodes() -> None:
    seeds = [3, 4, 5]
    holding = as_controller(lambda o, q, qd, t: -0.5 * q[0] - 0.05 * qd[0])
    full = evaluate_controller(holding, Task(start="upright"), seeds=seeds, duration_s=2.0)
    early = evaluate_controller(holding, Task(start="upright"), seeds=seeds, duration_s=2.0, stop_at_first_failure=True)
    assert full.successes == early.successes == 3  # every start succeeds: every start runs
    for a, b in zip(full.results, early.results):
        np.testing.assert_array_equal(a.observations, b.observations)
    idle = as_controller(lambda o, q, qd, t: 0.0)
    full = evaluate_controller(idle, seeds=seeds, duration_s=1.5)
    early = evaluate_controller(idle, seeds=seeds, duration_s=1.5, stop_at_first_failure=True)
    assert len(full.results) == 3 and [r.seed for r in early.results] == [3]  # stops after the first failure
    np.testing.assert_array_equal(early.results[0].observations, full.results[0].observations)
    with pytest.raises(ValueError, match="stop_at_first_failure"):
        evaluate_controller(idle, seeds=seeds, duration_s=1.5, stop_at_first_failure=1)


@pytest.mark.parametrize("engine", ["exudyn", "batched"])
def test_stop_at_first_failure_keeps_the_episodes_up_to_the_first_failure_on_either_engine(engine: str) -> None:
    idle = as_controller(lambda o, q, qd, t: 0.0)
    holding = as_controller(lambda o, q, qd, t: -0.5 * q[0] - 0.05 * qd[0])
    upright = Task(start="upright")
    held = evaluate(holding, upright, engine=engine, seeds=[3, 4], duration_s=1.5, stop_at_first_failure=True)
    assert [r.seed for r in held.results] == [3, 4] and held.successes == 2
    early = evaluate(idle, engine=engine, seeds=[3, 4, 5], duration_s=1.5, stop_at_first_failure=True)
    assert [r.seed for r in early.results] == [3] and early.successes == 0


@pytest.mark.parametrize("engine", ["exudyn", "batched"])
def test_an_exact_start_is_where_the_episode_starts_and_lqr_holds_it(engine: str) -> None:
    from softpend.control.lqr import LQRController

    task = Task(start="upright")
    tilt = task.tilt_state(0.2)
    lqr = LQRController.from_params(task.rod, dt_s=task.dt_s)
    (result,) = evaluate(lqr, task, engine=engine, seeds=(0,), duration_s=3.0, initial_state=tilt).results
    np.testing.assert_array_equal(result.joint_angles_rad[0], tilt[0])
    assert abs(result.theta_rad[0]) > 0.15 and result.success and result.swing_up_time_s < 0.2
    assert np.all(np.abs(result.theta_rad[-100:]) < 0.02)  # caught the 0.2 rad tilt and holds upright


def test_a_gym_policy_sees_what_its_environment_shows_and_leaves_the_environment_alone() -> None:
    """The vectors :class:`HeldActionController` rebuilds (the reward's bonus included) are the ones the environment
    returns when stepped with the same actions, and the environment it reads is not written to."""
    task = Task(start="upright", start_noise_rad=0.1)
    env = SoftPendulumDiscreteEnv(n_torque_levels=5, **task.env_kwargs())
    weights = np.random.default_rng(1).normal(size=11)
    seen: list[np.ndarray] = []

    def policy(vector: np.ndarray) -> int:
        return int(np.clip(np.round(2 + 2 * np.tanh(weights @ vector)), 0, 4))

    before = env.__dict__.copy()
    controller = HeldActionController(lambda vector: seen.append(vector.copy()) or policy(vector), env)
    result = evaluate(controller, task, seeds=(2,), duration_s=1.0).results[0]
    assert env.__dict__.keys() == before.keys() and all(env.__dict__[k] is v for k, v in before.items())
    shown = SoftPendulumDiscreteEnv(n_torque_levels=5, **task.env_kwargs())
    vector, _ = shown.reset(seed=2)
    assert len(seen) == 100
    for k, expected in enumerate(seen):
        np.testing.assert_array_equal(expected, vector)
        vector, _, _, _, info = shown.step(policy(vector))
        assert info["torque_nm"] == result.torque_nm[k]
    assert len({float(v[-1]) for v in seen}) > 2  # the bonus state went in, came out and decayed


def test_engine_arguments_are_refused_where_they_do_not_belong() -> None:
    idle = as_controller(lambda o, q, qd, t: 0.0)
    with pytest.raises(ValueError, match="engine must be one of"):
        evaluate(idle, engine="mujoco", seeds=(0,), duration_s=0.5)
    with pytest.raises(ValueError, match="batched engine"):
        evaluate(BatchPolicy(lambda v: np.zeros((len(v), 1))), seeds=(0,), duration_s=0.5)
    with pytest.raises(ValueError, match="batched engine"):
        evaluate(idle, seeds=(0,), duration_s=0.5, substeps=10)
    env = SoftPendulumDiscreteEnv()
    with pytest.raises(ValueError, match="initial_state must be a pair"):
        run_episode(idle, env, seed=0, duration_s=0.5, initial_state=np.zeros(5))

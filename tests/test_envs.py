"""The Gymnasium environments: API checks, determinism, reward, truncation, bad input."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import softpend  # noqa: F401  (registers the environments)
from softpend.envs import MAX_EPISODE_STEPS, RewardParams, SoftPendulumDiscreteEnv, SoftPendulumEnv, step_reward
from softpend.envs.reward import shaping_reward
from softpend.plant import RodParams, make_plant

ENV_IDS = ["softpend/SoftPendulum-v0", "softpend/SoftPendulumDiscrete-v0"]


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_envs_pass_gymnasium_and_sb3_checkers(env_id: str) -> None:
    gym_check_env(gym.make(env_id, render_mode="rgb_array").unwrapped)
    sb3_check_env(gym.make(env_id).unwrapped, warn=True)


@pytest.mark.parametrize("env_id", ENV_IDS)
def test_same_seed_and_actions_give_identical_trajectories(env_id: str) -> None:
    def rollout() -> np.ndarray:
        env = gym.make(env_id)
        env.action_space.seed(7)
        obs, _ = env.reset(seed=42)
        out = [obs]
        for _ in range(150):
            obs, reward, *_ = env.step(env.action_space.sample())
            out.append(np.append(obs, reward))
        return np.concatenate(out)

    np.testing.assert_array_equal(rollout(), rollout())


def test_different_seeds_give_different_starts() -> None:
    env = gym.make("softpend/SoftPendulum-v0")
    a, _ = env.reset(seed=0)
    b, _ = env.reset(seed=1)
    assert not np.array_equal(a, b)


def test_registered_episode_is_truncated_at_max_steps() -> None:
    env = gym.make("softpend/SoftPendulumDiscrete-v0")
    env.reset(seed=0)
    truncated = False
    steps = 0
    while not truncated:
        _, _, terminated, truncated, _ = env.step(2)
        assert not terminated
        steps += 1
    assert steps == MAX_EPISODE_STEPS == 1000


def test_start_states() -> None:
    env = SoftPendulumEnv()
    env.reset(seed=0)
    assert abs(abs(env.report_observation.theta_rad) - math.pi) < 0.1
    env.reset(seed=0, options={"start": "upright"})
    assert abs(env.report_observation.theta_rad) < 0.1
    with pytest.raises(ValueError, match="start"):
        env.reset(seed=0, options={"start": "sideways"})


def test_reward_shape_matches_report() -> None:
    # clipped cot|theta| scaled to [-1, 1]: -1 hanging, 0 horizontal, 1 within atan(1/50) of upright
    assert shaping_reward(math.pi - 1e-3) == pytest.approx(-1.0)
    assert shaping_reward(math.pi / 2) == pytest.approx(0.0, abs=1e-12)
    assert shaping_reward(0.0) == 1.0
    assert shaping_reward(0.01) == 1.0
    assert shaping_reward(0.2) == pytest.approx(1 / math.tan(0.2) / 50)
    theta = np.linspace(-math.pi, math.pi, 101)
    values = shaping_reward(theta)
    np.testing.assert_allclose(values, values[::-1], atol=1e-12)  # symmetric


def test_bonus_is_paid_inside_epsilon_and_decays_outside() -> None:
    params = RewardParams(epsilon_rad=0.1, bonus_decay_per_s=5.0)
    r_in, bonus = step_reward(0.05, 0.0, 0.01, params)
    assert bonus == 1.0 and r_in == pytest.approx(shaping_reward(0.05) + 1.0)
    r_out, bonus2 = step_reward(0.3, bonus, 0.01, params)
    assert bonus2 == pytest.approx(math.exp(-0.05))
    assert r_out == pytest.approx(shaping_reward(0.3) + bonus2)
    # vectorised form agrees with the scalar one
    r_vec, b_vec = step_reward(np.array([0.05, 0.3]), np.array([0.0, 1.0]), 0.01, params)
    np.testing.assert_allclose(r_vec, [r_in, r_out])


def test_env_reward_matches_reward_module() -> None:
    env = SoftPendulumEnv()
    vector, _ = env.reset(seed=3, options={"start": "upright"})
    bonus = float(vector[-1])  # the bonus state, 0 or 1 at a reset
    for k in range(50):
        obs, reward, *_ = env.step(np.array([0.3 * math.sin(k / 5)], dtype=np.float32))
        expected, bonus = step_reward(env.report_observation.theta_rad, bonus, env.dt_s, env.reward_params)
        assert reward == pytest.approx(expected)
        assert obs[-1] == pytest.approx(bonus, rel=1e-6)


def test_discrete_levels_and_action_validation() -> None:
    env = SoftPendulumDiscreteEnv(n_torque_levels=5, params=RodParams(torque_limit_nm=0.05))
    np.testing.assert_allclose(env.torque_levels_nm, [-0.05, -0.025, 0.0, 0.025, 0.05])
    env.reset(seed=0)
    _, _, _, _, info = env.step(4)
    assert info["torque_nm"] == pytest.approx(0.05)
    with pytest.raises(ValueError, match="action"):
        env.step(5)
    with pytest.raises(ValueError, match="n_torque_levels"):
        SoftPendulumDiscreteEnv(n_torque_levels=1)


def test_continuous_action_is_a_fraction_of_the_torque_limit() -> None:
    env = SoftPendulumEnv(params=RodParams(torque_limit_nm=0.04))
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([0.5], dtype=np.float32))
    assert info["torque_nm"] == pytest.approx(0.02)
    with pytest.raises(ValueError, match="action"):
        env.step(np.array([np.nan], dtype=np.float32))


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"dt_s": -0.01}, "dt_s"),
        ({"start": "sideways"}, "start"),
        ({"start_noise_rad": -1.0}, "start_noise_rad"),
        ({"plant": "nonexistent"}, "plant"),
    ],
)
def test_bad_env_arguments_raise(kwargs: dict, name: str) -> None:
    with pytest.raises(ValueError, match=name):
        SoftPendulumEnv(**kwargs)


def test_step_before_reset_raises() -> None:
    with pytest.raises(RuntimeError, match="reset"):
        SoftPendulumEnv().step(np.zeros(1, dtype=np.float32))


def test_diverging_simulation_truncates_with_reason_and_finite_observation() -> None:
    env = SoftPendulumEnv(params=RodParams(n_links=10, joint_damping_nms_per_rad=0.0, hub_friction_nms_per_rad=0.0))
    q = np.zeros(11)
    q[0], q[1] = 2.0, 0.2
    env.reset(seed=0, options={"q": q})
    for _ in range(1000):
        obs, reward, terminated, truncated, info = env.step(np.zeros(1, dtype=np.float32))
        assert np.all(np.isfinite(obs)) and math.isfinite(reward)
        if truncated:
            break
    assert truncated and "diverged" in info["truncation_reason"]


def test_render_returns_an_image() -> None:
    env = gym.make("softpend/SoftPendulum-v0", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (400, 400, 3) and frame.dtype == np.uint8
    assert (frame < 255).any()


def test_reset_options_start_the_plant_exactly_there_and_keep_the_draws() -> None:
    """``options={"q", "q_dot"}`` start the rod exactly at that state (as Gymnasium's pendulum reads its options); the
    generator advances as without them, and a closed loop from there is the plant's own from that state."""
    env = SoftPendulumEnv(start="upright")
    q, q_dot = np.zeros(5), np.zeros(5)
    q[0], q_dot[0] = 0.15, -0.3
    vector, info = env.reset(seed=4, options={"q": q, "q_dot": q_dot})
    np.testing.assert_array_equal(env.plant.joint_state()[0], q)
    np.testing.assert_array_equal(env.plant.joint_state()[1], q_dot)
    assert vector[-1] == 0.0 and abs(info["observation"][1] - 0.15) < 0.01  # tip tilted 0.15 rad: no bonus
    after_exact = env.np_random.uniform()
    env.reset(seed=4)
    assert env.np_random.uniform() == after_exact
    plant = make_plant("prb", params=env.params, dt_s=env.dt_s, substeps=2)
    plant.reset(q, q_dot)
    env.reset(seed=9, options={"q": q, "q_dot": q_dot})
    for k in range(30):
        action = np.array([0.3 * math.sin(k / 4)])
        expected = plant.step(env.torque_from_action(action))
        env.step(action)
        assert env.report_observation == expected


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"state": np.zeros(5)}, r"unknown reset option\(s\) \['state'\]"),
        ({"q": np.zeros(4)}, r"options\['q'\] must have shape \(5,\), got \(4,\)"),
        ({"q": np.zeros(5), "q_dot": np.zeros((2, 5))}, r"options\['q_dot'\] must have shape"),
        ({"q": np.full(5, np.nan)}, r"options\['q'\] must be finite"),
        ({"q_dot": np.zeros(5)}, r"options\['q_dot'\] needs options\['q'\]"),
        ({"start": "sideways"}, r"options\['start'\] must be one of"),
    ],
)
def test_bad_reset_options_are_refused_in_one_line(options: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match) as error:
        SoftPendulumEnv().reset(seed=0, options=options)
    assert "\n" not in str(error.value)

"""The vectorised observation vector of model rollouts equals the environment's own."""

import numpy as np
import pytest

from softpend.envs import SoftPendulumDiscreteEnv
from softpend.envs.reward import next_bonus
from softpend.envs.soft_pendulum import observation_vector
from softpend.plant import OBSERVATION_NAMES


def _trajectory(n_steps: int = 120):
    env = SoftPendulumDiscreteEnv(start="random")
    vec, _ = env.reset(seed=3)
    rng = np.random.default_rng(0)
    first = next_bonus(env.report_observation.theta_rad, 0.0, env.dt_s, env.reward_params)  # the bonus at a reset
    raws, bonuses, vecs = [env.report_observation.as_array()], [first], [vec]
    for _ in range(n_steps):
        vec, *_ = env.step(int(rng.integers(0, env.n_torque_levels)))
        theta = env.report_observation.theta_rad
        raws.append(env.report_observation.as_array())
        bonuses.append(next_bonus(theta, bonuses[-1], env.dt_s, env.reward_params))
        vecs.append(vec)
    return env, np.array(raws), np.array(bonuses), np.array(vecs)


def test_matches_environment_vector():
    env, raws, bonuses, vecs = _trajectory()
    np.testing.assert_allclose(observation_vector(raws, bonuses, env), vecs, rtol=0, atol=1e-6)


def test_clipped_like_environment():
    env = SoftPendulumDiscreteEnv()
    raw = np.zeros((1, len(OBSERVATION_NAMES)))
    raw[0, OBSERVATION_NAMES.index("phi_dot_rad_s")] = 400.0  # far beyond the 50 rad/s bound
    vec = observation_vector(raw, np.zeros(1), env)
    assert vec[0, 6] == pytest.approx(env.observation_space.high[6])


def test_bad_shape_raises():
    env = SoftPendulumDiscreteEnv()
    with pytest.raises(ValueError, match="observations"):
        observation_vector(np.zeros((3, 4)), np.zeros(3), env)

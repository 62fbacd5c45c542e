"""PILCO's exploration: the random-torque first trial with held bang-bang torques."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from softpend.envs import SoftPendulumEnv
from softpend.evaluation import run_episode
from softpend.pilco import PilcoConfig, RandomTorqueController
from softpend.plant import OBSERVATION_NAMES, Observation

torch.set_num_threads(1)
LIMIT_NM = 0.06


def _torques(controller: RandomTorqueController, n_periods: int) -> np.ndarray:
    controller.reset()
    obs = Observation(*np.zeros(len(OBSERVATION_NAMES)))
    return np.array([controller(obs, None, None, k * controller.control_dt_s) for k in range(n_periods)])


def test_random_controller_holds_bang_bang_torques_for_random_whole_periods():
    controller = RandomTorqueController(LIMIT_NM, 0.1, seed=0, hold_s=(0.2, 0.6))
    u = _torques(controller, 200)
    assert set(np.round(u / LIMIT_NM, 12)) == {-1.0, 1.0}
    # runs of one drawn torque last 2..6 periods (two equal draws in a row merge into a longer run)
    changes = np.flatnonzero(np.diff(u) != 0) + 1
    runs = np.diff(np.concatenate([[0], changes]))
    assert runs.min() >= 2 and np.median(runs) <= 6 and len(runs) > 15
    np.testing.assert_array_equal(u, _torques(controller, 200))  # reset re-seeds: reproducible
    assert not np.array_equal(u, _torques(RandomTorqueController(LIMIT_NM, 0.1, 1, (0.2, 0.6)), 200))
    with pytest.raises(ValueError, match="random_hold_max_s"):
        PilcoConfig(random_hold_min_s=0.6, random_hold_max_s=0.2)


def test_held_random_torques_swing_the_soft_rod_above_the_horizontal():
    """Physics: holding the torque for about half a swing pumps energy into the hanging rod."""
    env = SoftPendulumEnv(dt_s=0.01, start="hanging", start_noise_rad=0.05)
    theta = OBSERVATION_NAMES.index("theta_rad")

    def swing_rad(controller: RandomTorqueController, seed: int) -> float:
        episode = run_episode(controller, env, seed=seed, duration_s=4.0)
        return float(np.max(np.pi - np.abs(episode.observations[:, theta])))  # largest angle away from hanging

    held = [swing_rad(RandomTorqueController(LIMIT_NM, 0.1, s, (0.2, 0.6)), s) for s in range(3)]
    assert max(held) > np.pi / 2  # at least one random trial takes the tip above the horizontal

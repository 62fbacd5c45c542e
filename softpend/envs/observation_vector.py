"""The environment's observation vector for a batch of plant observations (for model rollouts)."""

from __future__ import annotations

from typing import Any

import numpy as np

from softpend.envs.soft_pendulum import VELOCITY_SCALE_PER_S
from softpend.plant import OBSERVATION_NAMES


def observation_vector(observations: np.ndarray, bonus: np.ndarray, env: Any) -> np.ndarray:
    """Rows ``env.observation_vector(observation, bonus)`` (float32, ``(B, 11)``) for plant observations
    ``(B, 10)`` and the reward's bonus state after each; ``env`` (single or vector) is not stepped."""
    observations = np.asarray(observations, dtype=np.float64)
    if observations.ndim != 2 or observations.shape[1] != len(OBSERVATION_NAMES):
        raise ValueError(f"observations must have shape (B, {len(OBSERVATION_NAMES)}), got {observations.shape}")
    bonus = np.broadcast_to(np.asarray(bonus, dtype=np.float64), (observations.shape[0],))
    env = env.unwrapped if hasattr(env, "unwrapped") else env
    inv_l, v = 1.0 / env.params.length_m, VELOCITY_SCALE_PER_S
    phi, theta, ex, ey, _, phi_dot, theta_dot, ex_dot, ey_dot, _ = observations.T
    angles = [np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta)]  # the order of OBSERVATION_VECTOR_NAMES
    rates = [phi_dot / v, theta_dot / v, ex_dot * inv_l / v, ey_dot * inv_l / v]
    vec = np.stack([*angles, ex * inv_l, ey * inv_l, *rates, bonus], axis=1).astype(np.float32)
    bound = env.observation_space.high
    return np.clip(vec, -bound, bound)

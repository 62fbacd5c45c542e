"""The environment's observation vector for a batch of plant observations (for model rollouts)."""

from __future__ import annotations

from typing import Any

import numpy as np

from softpend.envs.soft_pendulum import OBSERVATION_VECTOR_NAMES, VELOCITY_SCALE_PER_S
from softpend.plant import OBSERVATION_NAMES


def observation_vector(observations: np.ndarray, bonus: np.ndarray, env: Any) -> np.ndarray:
    """Rows ``env.observation_vector(observation, bonus)`` (float32, ``(B, 11)``) for plant observations
    ``(B, 10)`` and the reward's bonus state after each; ``env`` (single or vector) is not stepped."""
    observations = np.asarray(observations, dtype=np.float64)
    if observations.ndim != 2 or observations.shape[1] != len(OBSERVATION_NAMES):
        raise ValueError(f"observations must have shape (B, {len(OBSERVATION_NAMES)}), got {observations.shape}")
    bonus = np.broadcast_to(np.asarray(bonus, dtype=np.float64), (observations.shape[0],))
    env = env.unwrapped if hasattr(env, "unwrapped") else env
    inv_l = 1.0 / env.params.length_m
    v = VELOCITY_SCALE_PER_S
    o = dict(zip(OBSERVATION_NAMES, observations.T))
    columns = {
        "cos_phi": np.cos(o["phi_rad"]),
        "sin_phi": np.sin(o["phi_rad"]),
        "cos_theta": np.cos(o["theta_rad"]),
        "sin_theta": np.sin(o["theta_rad"]),
        "ex_over_L": o["ex_m"] * inv_l,
        "ey_over_L": o["ey_m"] * inv_l,
        "phi_dot_over_10": o["phi_dot_rad_s"] / v,
        "theta_dot_over_10": o["theta_dot_rad_s"] / v,
        "ex_dot_over_10L": o["ex_dot_m_s"] * inv_l / v,
        "ey_dot_over_10L": o["ey_dot_m_s"] * inv_l / v,
        "bonus": bonus,
    }
    vec = np.stack([columns[name] for name in OBSERVATION_VECTOR_NAMES], axis=1).astype(np.float32)
    bound = env.observation_space.high
    return np.clip(vec, -bound, bound)

"""The environment's observation vector and reward, vectorised over a batch (for model rollouts).

:class:`softpend.envs.SoftPendulumEnv` builds its observation vector one step at a time from a plant
:class:`~softpend.plant.Observation` (:meth:`SoftPendulumEnv.observation_vector`); a model-based learner needs the same
vector for thousands of *predicted* observations at once.  This module computes it with the environment's
own constants (:data:`~softpend.envs.soft_pendulum.OBSERVATION_VECTOR_NAMES`, ``VELOCITY_SCALE_PER_S``, the
observation-space bound) (the reward comes from the shared vectorised :func:`~softpend.envs.step_reward`), so
that a model transition looks exactly like a real one.  ``tests/test_env_observation_vector.py`` checks the
equality against the environment.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from softpend.envs.soft_pendulum import OBSERVATION_VECTOR_NAMES, VELOCITY_SCALE_PER_S
from softpend.plant import OBSERVATION_NAMES

__all__ = ["observation_vector", "observations_from_vector"]

_I = {name: OBSERVATION_NAMES.index(name) for name in OBSERVATION_NAMES}


def observation_vector(observations: np.ndarray, bonus: np.ndarray, env: Any) -> np.ndarray:
    """Environment observation vectors for a batch of plant observations.

    Parameters
    ----------
    observations : ndarray, shape (B, 10)
        Plant observations in :data:`softpend.plant.OBSERVATION_NAMES` order [rad, m, rad/s, m/s].
    bonus : ndarray, shape (B,)
        The reward's bonus state ``r*`` after the step that produced each observation.
    env : SoftPendulumEnv or SoftPendulumVectorEnv
        Environment whose conventions (rod length, bound) the vector follows (not stepped).

    Returns
    -------
    ndarray, shape (B, 11), float32
        Rows equal to ``env.observation_vector(observation, bonus)``.
    """
    observations = np.asarray(observations, dtype=np.float64)
    if observations.ndim != 2 or observations.shape[1] != len(OBSERVATION_NAMES):
        raise ValueError(f"observations must have shape (B, {len(OBSERVATION_NAMES)}), got {observations.shape}")
    bonus = np.broadcast_to(np.asarray(bonus, dtype=np.float64), (observations.shape[0],))
    env = env.unwrapped if hasattr(env, "unwrapped") else env
    inv_l = 1.0 / env.params.length_m
    v = VELOCITY_SCALE_PER_S
    phi, theta = observations[:, _I["phi_rad"]], observations[:, _I["theta_rad"]]
    columns = {
        "cos_phi": np.cos(phi),
        "sin_phi": np.sin(phi),
        "cos_theta": np.cos(theta),
        "sin_theta": np.sin(theta),
        "ex_over_L": observations[:, _I["ex_m"]] * inv_l,
        "ey_over_L": observations[:, _I["ey_m"]] * inv_l,
        "phi_dot_over_10": observations[:, _I["phi_dot_rad_s"]] / v,
        "theta_dot_over_10": observations[:, _I["theta_dot_rad_s"]] / v,
        "ex_dot_over_10L": observations[:, _I["ex_dot_m_s"]] * inv_l / v,
        "ey_dot_over_10L": observations[:, _I["ey_dot_m_s"]] * inv_l / v,
        "bonus": bonus,
    }
    vec = np.stack([columns[name] for name in OBSERVATION_VECTOR_NAMES], axis=1).astype(np.float32)
    bound = env.observation_space.high
    return np.clip(vec, -bound, bound)


def observations_from_vector(vectors: np.ndarray, env: Any) -> np.ndarray:
    """Invert :func:`observation_vector` where possible: plant observations (B, 10) from env vectors (B, 11).

    The tip rotation ``er`` and its rate are not part of the vector; they are set to ``theta`` and
    ``theta_dot`` (exact for a straight rod).  Velocities clipped by the vector's bound stay clipped.
    """
    vectors = np.asarray(vectors, dtype=np.float64)
    if vectors.ndim != 2 or vectors.shape[1] != len(OBSERVATION_VECTOR_NAMES):
        raise ValueError(f"vectors must have shape (B, {len(OBSERVATION_VECTOR_NAMES)}), got {vectors.shape}")
    env = env.unwrapped if hasattr(env, "unwrapped") else env
    col = {name: vectors[:, i] for i, name in enumerate(OBSERVATION_VECTOR_NAMES)}
    length = env.params.length_m
    v = VELOCITY_SCALE_PER_S
    out = np.empty((vectors.shape[0], len(OBSERVATION_NAMES)))
    out[:, _I["phi_rad"]] = np.arctan2(col["sin_phi"], col["cos_phi"])
    out[:, _I["theta_rad"]] = np.arctan2(col["sin_theta"], col["cos_theta"])
    out[:, _I["ex_m"]] = col["ex_over_L"] * length
    out[:, _I["ey_m"]] = col["ey_over_L"] * length
    out[:, _I["er_rad"]] = out[:, _I["theta_rad"]]
    out[:, _I["phi_dot_rad_s"]] = col["phi_dot_over_10"] * v
    out[:, _I["theta_dot_rad_s"]] = col["theta_dot_over_10"] * v
    out[:, _I["ex_dot_m_s"]] = col["ex_dot_over_10L"] * length * v
    out[:, _I["ey_dot_m_s"]] = col["ey_dot_over_10L"] * length * v
    out[:, _I["er_dot_rad_s"]] = out[:, _I["theta_dot_rad_s"]]
    return out

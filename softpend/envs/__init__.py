"""Gymnasium environments of the soft pendulum task (registered by entry point on ``import softpend``)."""

from softpend import MAX_EPISODE_STEPS
from softpend.envs.reward import RewardParams, shaping_reward, step_reward
from softpend.envs.soft_pendulum import OBSERVATION_VECTOR_NAMES, SoftPendulumDiscreteEnv, SoftPendulumEnv

__all__ = [
    "MAX_EPISODE_STEPS",
    "OBSERVATION_VECTOR_NAMES",
    "RewardParams",
    "SoftPendulumDiscreteEnv",
    "SoftPendulumEnv",
    "shaping_reward",
    "step_reward",
]

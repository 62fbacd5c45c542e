"""Gymnasium environments of the soft pendulum task (registered by entry point on ``import softpend``)."""

from softpend import MAX_EPISODE_STEPS
from softpend.envs.reward import RewardParams, step_reward
from softpend.envs.soft_pendulum import SoftPendulumDiscreteEnv, SoftPendulumEnv

__all__ = ["MAX_EPISODE_STEPS", "RewardParams", "SoftPendulumDiscreteEnv", "SoftPendulumEnv", "step_reward"]

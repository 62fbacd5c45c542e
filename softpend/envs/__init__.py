"""Gymnasium environments of the soft pendulum task (registered on ``import softpend``)."""

from gymnasium.envs.registration import register, registry

from .reward import RewardParams, shaping_reward, step_reward
from .soft_pendulum import OBSERVATION_VECTOR_NAMES, SoftPendulumDiscreteEnv, SoftPendulumEnv

#: Episode length of the registered environments (10 s at dt = 0.01 s).
MAX_EPISODE_STEPS = 1000

for _env_id, _entry in (
    ("softpend/SoftPendulum-v0", "softpend.envs.soft_pendulum:SoftPendulumEnv"),
    ("softpend/SoftPendulumDiscrete-v0", "softpend.envs.soft_pendulum:SoftPendulumDiscreteEnv"),
):
    if _env_id not in registry:
        register(id=_env_id, entry_point=_entry, max_episode_steps=MAX_EPISODE_STEPS)

__all__ = [
    "MAX_EPISODE_STEPS",
    "OBSERVATION_VECTOR_NAMES",
    "RewardParams",
    "SoftPendulumDiscreteEnv",
    "SoftPendulumEnv",
    "shaping_reward",
    "step_reward",
]

"""softpend: learning to control a soft robotic pendulum.

Importing the package registers the Gymnasium environments ``softpend/SoftPendulum-v0`` and
``softpend/SoftPendulumDiscrete-v0`` by ``"module:Class"`` entry points (and vector entry points for
``gymnasium.make_vec``); their modules (and Exudyn or torch) are imported only when an environment is made.
"""

from importlib.metadata import PackageNotFoundError, version

from gymnasium.envs.registration import register as _register
from gymnasium.envs.registration import registry as _registry

try:
    __version__ = version("softpend")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.1.0"

#: Episode length of the registered environments (10 s at dt = 0.01 s).
MAX_EPISODE_STEPS = 1000

#: Registered environment id -> entry point.
ENVIRONMENTS = {
    "softpend/SoftPendulum-v0": "softpend.envs.soft_pendulum:SoftPendulumEnv",
    "softpend/SoftPendulumDiscrete-v0": "softpend.envs.soft_pendulum:SoftPendulumDiscreteEnv",
}

#: Registered environment id -> vector entry point (``gymnasium.make_vec`` builds these by default: all rods
#: on the batched torch chain, :mod:`softpend.envs.vector`; ``vectorization_mode="sync"`` gives Exudyn copies).
VECTOR_ENVIRONMENTS = {
    "softpend/SoftPendulum-v0": "softpend.envs.vector:SoftPendulumVectorEnv",
    "softpend/SoftPendulumDiscrete-v0": "softpend.envs.vector:SoftPendulumDiscreteVectorEnv",
}

for _env_id, _entry in ENVIRONMENTS.items():
    if _env_id not in _registry:
        _register(
            id=_env_id,
            entry_point=_entry,
            vector_entry_point=VECTOR_ENVIRONMENTS.get(_env_id),
            max_episode_steps=MAX_EPISODE_STEPS,
        )

__all__ = ["ENVIRONMENTS", "MAX_EPISODE_STEPS", "VECTOR_ENVIRONMENTS", "__version__"]

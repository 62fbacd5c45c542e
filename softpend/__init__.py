"""softpend: learning to control a soft robotic pendulum.

Importing the package registers the Gymnasium environments ``softpend/SoftPendulum-v0`` and
``softpend/SoftPendulumDiscrete-v0`` by ``"module:Class"`` entry points; their modules (and Exudyn) are
imported only when an environment is made.
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

for _env_id, _entry in ENVIRONMENTS.items():
    if _env_id not in _registry:
        _register(id=_env_id, entry_point=_entry, max_episode_steps=MAX_EPISODE_STEPS)

__all__ = ["ENVIRONMENTS", "MAX_EPISODE_STEPS", "__version__"]

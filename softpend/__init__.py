"""softpend: learning to control a soft robotic pendulum.

Importing the package registers the Gymnasium environments ``softpend/SoftPendulum-v0`` and
``softpend/SoftPendulumDiscrete-v0``.
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("softpend")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.1.0"

from . import envs as _envs  # noqa: E402,F401  (registers the environments)

__all__ = ["__version__"]

"""Plants: the simulated soft pendulum and its parameters."""

from .observation import OBSERVATION_NAMES, Observation, wrap_angle_rad
from .params import GRAVITY_MPS2, RodParams
from .base import SimulationDiverged
from .prb import PRBPlant
from .registry import check_plant_name, make_plant, plant_names, register_plant

__all__ = [
    "GRAVITY_MPS2",
    "OBSERVATION_NAMES",
    "Observation",
    "PRBPlant",
    "RodParams",
    "SimulationDiverged",
    "wrap_angle_rad",
    "check_plant_name",
    "make_plant",
    "plant_names",
    "register_plant",
]

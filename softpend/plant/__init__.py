"""Plants: the simulated soft pendulum and its parameters."""

from softpend.plant.base import SimulationDiverged
from softpend.plant.observation import OBSERVATION_NAMES, Observation, wrap_angle_rad
from softpend.plant.params import RodParams
from softpend.plant.prb import PRBPlant
from softpend.plant.registry import check_plant_name, make_plant, plant_names, tilt_state

__all__ = [
    "OBSERVATION_NAMES",
    "Observation",
    "PRBPlant",
    "RodParams",
    "SimulationDiverged",
    "wrap_angle_rad",
    "check_plant_name",
    "make_plant",
    "plant_names",
    "tilt_state",
]

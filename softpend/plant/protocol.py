"""The interface every plant implements, as a protocol type checkers see."""

from __future__ import annotations

from typing import Optional, Protocol, runtime_checkable

import numpy as np

from softpend.plant.observation import Observation
from softpend.plant.params import RodParams


@runtime_checkable
class Plant(Protocol):
    """What environments, controllers, the evaluation and the rig emulator use of a plant; ``q`` is the
    coordinate vector, hub angle first (unwrapped) unless the hub is locked."""

    params: RodParams
    dt_s: float
    substeps: int
    n_coordinates: int
    last_torque_nm: float

    @property
    def time_s(self) -> float:
        """Simulated time since the last reset [s]."""

    def reset(
        self, joint_angles_rad: Optional[np.ndarray] = None, joint_velocities_rad_s: Optional[np.ndarray] = None
    ) -> Observation:
        """Restart from ``(q, q_dot)`` (default: the straight rod upright at rest)."""

    def step(self, torque_nm: float) -> Observation:
        """Hold ``torque_nm`` (saturated) for one step ``dt_s``."""

    def observe(self) -> Observation:
        """The observed variables now."""

    def observation_from_state(self, q: np.ndarray, q_dot: np.ndarray) -> Observation:
        """The observation of a given state (the plant is not changed)."""

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """``(q, q_dot)`` now (copies)."""

    def hanging_state(self) -> tuple[np.ndarray, np.ndarray]:
        """The straight rod hanging down at rest."""

    def link_points_m(self, q: Optional[np.ndarray] = None) -> np.ndarray:
        """Points along the rod, hub first [m]."""

    def energy_j(self, q: Optional[np.ndarray] = None, qd: Optional[np.ndarray] = None) -> dict[str, float]:
        """Kinetic, gravitational, elastic and total energy [J]."""

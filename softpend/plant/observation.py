"""What the plant reports: the report's observed variables and their time derivatives."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np


def wrap_angle_rad(angle: np.ndarray | float) -> np.ndarray | float:
    """Wrap an angle to ``[-pi, pi)``."""
    return (np.asarray(angle) + np.pi if np.ndim(angle) else angle + np.pi) % (2 * np.pi) - np.pi


class Observation(NamedTuple):
    """One sample of the observed variables: hub angle ``phi``, tip angle ``theta`` (of the tip position seen
    from the hub axis), tip position ``(ex, ey)`` from the hub axis, tip rotation ``er`` (the last link's
    angle), and their rates; angles from upright, wrapped to ``[-pi, pi)``."""

    phi_rad: float
    theta_rad: float
    ex_m: float
    ey_m: float
    er_rad: float
    phi_dot_rad_s: float
    theta_dot_rad_s: float
    ex_dot_m_s: float
    ey_dot_m_s: float
    er_dot_rad_s: float

    def as_array(self) -> np.ndarray:
        """The values in :data:`OBSERVATION_NAMES` order (float64)."""
        return np.array(self, dtype=np.float64)

    @classmethod
    def from_array(cls, values: np.ndarray) -> "Observation":
        values = np.asarray(values, dtype=float).reshape(-1)
        if values.shape[0] != len(cls._fields):
            raise ValueError(f"expected {len(cls._fields)} values, got {values.shape[0]}")
        return cls(*map(float, values))


#: The field names: the order of :meth:`Observation.as_array`.
OBSERVATION_NAMES: tuple[str, ...] = Observation._fields

_TWO_PI = 2 * math.pi


def observation_from_tip(phi, phi_dot, ex, ey, ex_dot, ey_dot, er, er_dot) -> Observation:
    """The :class:`Observation` of a hub angle [rad] and rate [rad/s], a tip position [m] and velocity [m/s], and a
    tip rotation [rad] and rate [rad/s]."""
    r2 = ex * ex + ey * ey
    theta_dot = (ex * ey_dot - ey * ex_dot) / r2 if r2 > 0 else 0.0
    phi, theta, er = ((x + math.pi) % _TWO_PI - math.pi for x in (phi, math.atan2(-ex, ey), er))
    return Observation(phi, theta, ex, ey, er, phi_dot, theta_dot, ex_dot, ey_dot, er_dot)


def energies(kinetic, gravity, elastic) -> dict:
    """The energy dict of a plant's ``energy_j``."""
    return {"kinetic_j": kinetic, "gravity_j": gravity, "elastic_j": elastic, "total_j": kinetic + gravity + elastic}

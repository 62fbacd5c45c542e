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


def observation_from_tip(
    phi_rad: float,
    phi_dot_rad_s: float,
    ex_m: float,
    ey_m: float,
    ex_dot_m_s: float,
    ey_dot_m_s: float,
    er_rad: float,
    er_dot_rad_s: float,
) -> Observation:
    """The :class:`Observation` of a hub angle, tip position and tip rotation (with rates)."""
    r2 = ex_m * ex_m + ey_m * ey_m
    theta_dot = (ex_m * ey_dot_m_s - ey_m * ex_dot_m_s) / r2 if r2 > 0 else 0.0
    phi, theta, er = ((x + math.pi) % _TWO_PI - math.pi for x in (phi_rad, math.atan2(-ex_m, ey_m), er_rad))
    return Observation(phi, theta, ex_m, ey_m, er, phi_dot_rad_s, theta_dot, ex_dot_m_s, ey_dot_m_s, er_dot_rad_s)


def energies(kinetic, gravity, elastic) -> dict:
    """The energy dict of a plant's ``energy_j``."""
    return {"kinetic_j": kinetic, "gravity_j": gravity, "elastic_j": elastic, "total_j": kinetic + gravity + elastic}

"""The observed variables of system identification (a view on the plant's observation), and their velocities
by causal numerical differentiation of sampled positions, as a rig does it (angles unwrapped first)."""

from __future__ import annotations

import numpy as np

from softpend.plant import OBSERVATION_NAMES

#: The sampled positions ``phi, theta, e_x, e_y, e_r`` and their time derivatives, same order.
POSITION_NAMES: tuple[str, ...] = OBSERVATION_NAMES[:5]
VELOCITY_NAMES: tuple[str, ...] = OBSERVATION_NAMES[5:]
#: Position variables that are angles (wrapped to ``[-pi, pi)``).
ANGLE_NAMES: frozenset[str] = frozenset({"phi_rad", "theta_rad", "er_rad"})


def velocity_name(position_name: str) -> str:
    """Name of the derivative of a position variable (``"ex_m"`` -> ``"ex_dot_m_s"``)."""
    if position_name not in POSITION_NAMES:
        raise ValueError(f"position_name must be one of {POSITION_NAMES}, got {position_name!r}")
    return VELOCITY_NAMES[POSITION_NAMES.index(position_name)]


def is_angle(name: str) -> bool:
    return name in ANGLE_NAMES


def backward_difference(positions: np.ndarray, dt_s: float, angle_mask: np.ndarray) -> np.ndarray:
    """``v[t] = (x[t] - x[t-1]) / dt`` of positions ``(..., N >= 2, P)`` at samples ``1 .. N - 1``, the columns in
    ``angle_mask (P,)`` unwrapped along time first."""
    positions = np.array(positions, dtype=np.float64)
    if positions.ndim < 2 or positions.shape[-2] < 2:
        raise ValueError(f"positions must have shape (..., n_samples >= 2, n_variables), got {positions.shape}")
    angle_mask = np.asarray(angle_mask, dtype=bool)
    if angle_mask.shape != (positions.shape[-1],):
        raise ValueError(f"angle_mask must have shape ({positions.shape[-1]},), got {angle_mask.shape}")
    if angle_mask.any():
        positions[..., angle_mask] = np.unwrap(positions[..., angle_mask], axis=-2)
    return np.diff(positions, axis=-2) / dt_s

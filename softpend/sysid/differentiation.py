"""Numerical differentiation of sampled positions, as a rig would do it.

A rig samples positions (encoder angle, camera tip position) and has no velocity sensor, so the
velocities that enter the dynamics model are differences of consecutive samples.  The difference is
*backward* (causal): the velocity at sample ``t`` uses samples ``t`` and ``t - 1`` only, so a state never
contains information from the future (a central difference would leak the next sample into the state
and make one-step prediction trivially easy).  Angles are unwrapped along time first, so that a
crossing of the ``+-pi`` seam does not look like a jump of ``2 pi``.
"""

from __future__ import annotations

import numpy as np

from softpend.checks import positive

__all__ = ["backward_difference", "unwrap_angles"]


def unwrap_angles(positions: np.ndarray, angle_mask: np.ndarray, axis: int = -2) -> np.ndarray:
    """Unwrap the angle columns of ``positions`` along the time axis (a copy).

    Parameters
    ----------
    positions : ndarray, shape (..., n_samples, n_variables)
        Sampled positions; angle columns in radians, wrapped or not.
    angle_mask : ndarray of bool, shape (n_variables,)
        Which columns are angles.
    axis : int
        The time axis (default: the second-to-last).
    """
    positions = np.array(positions, dtype=np.float64)
    angle_mask = np.asarray(angle_mask, dtype=bool)
    if angle_mask.shape != (positions.shape[-1],):
        raise ValueError(f"angle_mask must have shape ({positions.shape[-1]},), got {angle_mask.shape}")
    if angle_mask.any():
        positions[..., angle_mask] = np.unwrap(positions[..., angle_mask], axis=axis)
    return positions


def backward_difference(positions: np.ndarray, dt_s: float, angle_mask: np.ndarray) -> np.ndarray:
    """Causal first derivative ``v[t] = (x[t] - x[t-1]) / dt`` of sampled positions.

    Parameters
    ----------
    positions : ndarray, shape (..., n_samples, n_variables)
        Sampled positions [rad or m] at a fixed step ``dt_s``; angle columns may be wrapped.
    dt_s : float
        Sampling step [s].
    angle_mask : ndarray of bool, shape (n_variables,)
        Which columns are angles (unwrapped before differencing).

    Returns
    -------
    ndarray, shape (..., n_samples - 1, n_variables)
        Velocity estimates [rad/s or m/s] at samples ``1 .. n_samples - 1`` (the first sample has no
        predecessor).  The error on a smooth signal is ``x''(t) dt / 2 + O(dt^2)`` (first order).
    """
    positive("dt_s", dt_s)
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim < 2 or positions.shape[-2] < 2:
        raise ValueError(f"positions must have shape (..., n_samples >= 2, n_variables), got {positions.shape}")
    unwrapped = unwrap_angles(positions, angle_mask)
    return np.diff(unwrapped, axis=-2) / dt_s

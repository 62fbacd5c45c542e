"""Causal numerical differentiation of sampled positions, as a rig does it (angles unwrapped first)."""

from __future__ import annotations

import numpy as np

from softpend.checks import positive


def backward_difference(positions: np.ndarray, dt_s: float, angle_mask: np.ndarray) -> np.ndarray:
    """``v[t] = (x[t] - x[t-1]) / dt`` of positions ``(..., N, P)`` at samples ``1 .. N - 1``, the columns in
    ``angle_mask`` unwrapped along time first."""
    positive("dt_s", dt_s)
    positions = np.array(positions, dtype=np.float64)
    if positions.ndim < 2 or positions.shape[-2] < 2:
        raise ValueError(f"positions must have shape (..., n_samples >= 2, n_variables), got {positions.shape}")
    angle_mask = np.asarray(angle_mask, dtype=bool)
    if angle_mask.shape != (positions.shape[-1],):
        raise ValueError(f"angle_mask must have shape ({positions.shape[-1]},), got {angle_mask.shape}")
    if angle_mask.any():
        positions[..., angle_mask] = np.unwrap(positions[..., angle_mask], axis=-2)
    return np.diff(positions, axis=-2) / dt_s

"""Causal numerical differentiation of sampled positions, as a rig does it (angles unwrapped first)."""

from __future__ import annotations

import numpy as np


def backward_difference(positions: np.ndarray, dt_s: float, angle_mask: np.ndarray) -> np.ndarray:
    """``v[t] = (x[t] - x[t-1]) / dt`` of positions ``(..., N >= 2, P)`` at samples ``1 .. N - 1``, the columns in
    ``angle_mask (P,)`` unwrapped along time first."""
    positions = np.array(positions, dtype=np.float64)
    angle_mask = np.asarray(angle_mask, dtype=bool)
    if angle_mask.any():
        positions[..., angle_mask] = np.unwrap(positions[..., angle_mask], axis=-2)
    return np.diff(positions, axis=-2) / dt_s

"""Batched open-loop rollouts of a learned dynamics model."""

from __future__ import annotations

from typing import Any, Optional

import torch
from torch import Tensor


def rollout(model: Any, x0: Tensor, torques_nm: Tensor, generator: Optional[torch.Generator] = None) -> Tensor:
    """``x0 (B, d)`` followed by the ``T`` states a model (anything with ``predict_next``; an ensemble draws its
    members from ``generator``) predicts under torques ``(B, T)``: shape ``(B, T + 1, d)``."""
    if x0.ndim != 2:
        raise ValueError(f"x0 must have shape (B, d), got {tuple(x0.shape)}")
    if torques_nm.ndim != 2 or torques_nm.shape[0] != x0.shape[0]:
        raise ValueError(f"torques_nm must have shape ({x0.shape[0]}, T), got {tuple(torques_nm.shape)}")
    steps = [x0]
    for t in range(torques_nm.shape[1]):
        steps.append(model.predict_next(steps[-1], torques_nm[:, t], generator=generator))
    return torch.stack(steps, dim=1)

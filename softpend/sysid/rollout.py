"""Batched open-loop rollouts of a learned dynamics model."""

from __future__ import annotations

from typing import Optional, Protocol

import torch
from torch import Tensor

__all__ = ["rollout", "SupportsPredictNext"]


class SupportsPredictNext(Protocol):
    """Anything with ``predict_next(state (B, d), torque_nm (B,), generator=None) -> (B, d)``."""

    def predict_next(self, state: Tensor, torque_nm: Tensor, generator: Optional[torch.Generator] = None) -> Tensor: ...


def rollout(
    model: SupportsPredictNext,
    x0: Tensor,
    torques_nm: Tensor,
    generator: Optional[torch.Generator] = None,
) -> Tensor:
    """Roll a model forward open loop from many initial states under given torque sequences.

    Parameters
    ----------
    model : DynamicsModel or DynamicsEnsemble
        Anything with ``predict_next``; an ensemble picks a random member per row and step from
        ``generator``.
    x0 : Tensor, shape (B, d)
        Initial states (layout of ``model.layout``).
    torques_nm : Tensor, shape (B, T)
        Torque applied at each step [N m].
    generator : torch.Generator, optional
        Random source for ensemble member choice.

    Returns
    -------
    Tensor, shape (B, T + 1, d)
        ``x0`` followed by the ``T`` predicted states.  Gradients flow unless the caller disables them
        (wrap in ``torch.inference_mode()`` for speed).
    """
    if x0.ndim != 2:
        raise ValueError(f"x0 must have shape (B, d), got {tuple(x0.shape)}")
    if torques_nm.ndim != 2 or torques_nm.shape[0] != x0.shape[0]:
        raise ValueError(f"torques_nm must have shape ({x0.shape[0]}, T), got {tuple(torques_nm.shape)}")
    steps = [x0]
    x = x0
    for t in range(torques_nm.shape[1]):
        x = model.predict_next(x, torques_nm[:, t], generator=generator)
        steps.append(x)
    return torch.stack(steps, dim=1)

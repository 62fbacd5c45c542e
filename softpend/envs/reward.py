"""The report's reward (eqs. 4-5): ``r_t = clip(cot|theta|, -c, c) / c + w r*_t``, the bonus ``r*_t`` 1 while
``|theta| < epsilon`` and decaying at ``k`` [1/s] after.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from softpend.checks import non_negative, positive


@dataclass(frozen=True)
class RewardParams:
    """``c``, ``epsilon``, ``w`` and ``k`` of the reward."""

    clip_value: float = 50.0
    epsilon_rad: float = 0.1
    bonus_weight: float = 1.0
    bonus_decay_per_s: float = 5.0

    def __post_init__(self) -> None:
        for name in ("clip_value", "epsilon_rad"):
            positive(name, getattr(self, name))
        for name in ("bonus_weight", "bonus_decay_per_s"):
            non_negative(name, getattr(self, name))


def shaping_reward(theta_rad: np.ndarray | float, clip_value: float = 50.0) -> np.ndarray | float:
    """``clip(cos(theta)/|sin(theta)|, -c, c) / c`` (vectorised; ``theta = 0`` gives 1)."""
    theta = np.asarray(theta_rad, dtype=float)
    sin_abs = np.abs(np.sin(theta))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(sin_abs > 0, np.cos(theta) / np.maximum(sin_abs, 1e-300), np.sign(np.cos(theta)) * np.inf)
    value = np.clip(ratio, -clip_value, clip_value) / clip_value
    return float(value) if np.ndim(theta_rad) == 0 else value


def next_bonus(
    theta_rad: np.ndarray | float, previous_bonus: np.ndarray | float, dt_s: float, params: RewardParams
) -> np.ndarray | float:
    """Bonus ``r*_t`` from the tip angle and the previous bonus (vectorised)."""
    inside = np.abs(theta_rad) < params.epsilon_rad
    value = np.where(inside, 1.0, np.asarray(previous_bonus, dtype=float) * math.exp(-params.bonus_decay_per_s * dt_s))
    return float(value) if np.ndim(value) == 0 else value


def step_reward(theta_rad, previous_bonus, dt_s: float, params: RewardParams = RewardParams()):
    """One step of the reward (vectorised): ``(r_t, r*_t)``."""
    bonus = next_bonus(theta_rad, previous_bonus, dt_s, params)
    reward = shaping_reward(theta_rad, params.clip_value) + params.bonus_weight * np.asarray(bonus)
    return (float(reward) if np.ndim(reward) == 0 else reward), bonus

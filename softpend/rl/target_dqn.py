"""DQN whose TD targets are clipped to the bounds of the discounted return."""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
import torch
import torch.nn.functional as F
from stable_baselines3 import DQN


class TargetDQN(DQN):
    """:class:`stable_baselines3.DQN` whose gradient steps clamp the TD targets to ``q_target_bounds``."""

    def __init__(self, *args, q_target_bounds: Optional[tuple[float, float]] = None, **kwargs) -> None:
        if q_target_bounds is not None:
            low, high = (float(v) for v in q_target_bounds)
            if not (math.isfinite(low) and math.isfinite(high) and low < high):
                raise ValueError(f"q_target_bounds must be finite (low, high) with low < high, got {q_target_bounds!r}")
            q_target_bounds = (low, high)
        self.q_target_bounds = q_target_bounds
        super().__init__(*args, **kwargs)

    def td_targets(
        self,
        rewards: torch.Tensor,
        dones: torch.Tensor,
        discounts: torch.Tensor | float,
        next_observations: torch.Tensor,
    ) -> torch.Tensor:
        """TD targets of a batch (no gradient)."""
        with torch.no_grad():
            next_q_target = self.q_net_target(next_observations)
            target = rewards + (1 - dones) * discounts * next_q_target.max(dim=1, keepdim=True)[0]
            bounds = getattr(self, "q_target_bounds", None)  # an agent saved without the attribute has none
            if bounds is not None:
                target = target.clamp(bounds[0], bounds[1])
        return target

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:  # noqa: D102 (SB3 API)
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        losses = []
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            discounts = data.discounts if data.discounts is not None else self.gamma
            target = self.td_targets(data.rewards, data.dones, discounts, data.next_observations)
            current = torch.gather(self.q_net(data.observations), dim=1, index=data.actions.long())
            loss = F.smooth_l1_loss(current, target)
            losses.append(loss.item())
            self.policy.optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            self.policy.optimizer.step()
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", float(np.mean(losses)) if losses else float("nan"))

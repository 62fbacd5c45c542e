"""Double DQN: stable-baselines3's DQN with van Hasselt et al.'s (2016) decoupled target.

Vanilla DQN regresses on ``r + gamma * max_a Q_target(s', a)``, which overestimates the value wherever the
target network's errors are positive -- and with many gradient steps per real step on partly model-generated
data (DQN-MBPO) those errors are large.  Double DQN lets the *online* network choose the next action and the
target network value it, ``r + gamma * Q_target(s', argmax_a Q(s', a))``, the DQN counterpart of the clipped
double-Q critic that MBPO's SAC uses.  Everything else (Huber loss, gradient clipping, n-step discounts,
Polyak target updates) is stable-baselines3's.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from stable_baselines3 import DQN

__all__ = ["DoubleDQN", "double_q_targets"]


def double_q_targets(rewards: torch.Tensor, dones: torch.Tensor, discounts: torch.Tensor | float,
                     next_q_online: torch.Tensor, next_q_target: torch.Tensor) -> torch.Tensor:
    """Double-DQN TD targets ``r + (1 - done) * discount * Q_target(s', argmax_a Q_online(s', a))``.

    Parameters
    ----------
    rewards, dones : (B, 1) tensors
        Rewards and terminal flags of the batch.
    discounts : (B, 1) tensor or float
        Discount per transition (``gamma`` or ``gamma**n`` for n-step returns).
    next_q_online, next_q_target : (B, n_actions) tensors
        Q-values of the next observations under the online and the target network.
    """
    if next_q_online.shape != next_q_target.shape:
        raise ValueError(f"next_q_online and next_q_target must have the same shape, got {tuple(next_q_online.shape)} "
                         f"and {tuple(next_q_target.shape)}")
    best = next_q_online.argmax(dim=1, keepdim=True)
    return rewards + (1 - dones) * discounts * torch.gather(next_q_target, 1, best)


class DoubleDQN(DQN):
    """:class:`stable_baselines3.DQN` whose gradient steps use :func:`double_q_targets`."""

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:  # noqa: D102 (SB3 API)
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        losses = []
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            discounts = data.discounts if data.discounts is not None else self.gamma
            with torch.no_grad():
                target = double_q_targets(data.rewards, data.dones, discounts,
                                          self.q_net(data.next_observations), self.q_net_target(data.next_observations))
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

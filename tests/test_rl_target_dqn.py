"""Clipped TD targets on hand-made Q-values, and the gradient step that uses them."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from stable_baselines3 import DQN

from softpend.rl.config import DQNConfig, DQNLearner
from softpend.rl.dqn import TargetDQN, agent_class, build_dqn
from softpend.rl.training_env import make_training_env


def test_target_dqn_gradient_step_regresses_on_the_clipped_target(tmp_path):
    config = DQNConfig(
        episode_s=0.4, learning_starts=0, learner=DQNLearner(clip_q_targets=True, target_update_interval=1)
    )
    model = build_dqn(config, make_training_env(config), seed=0, episodes=1)
    assert isinstance(model, TargetDQN) and model.tau == 1.0  # the target network is a hard copy
    # a buffer of one repeated transition, so that every sampled batch is the same
    obs = np.linspace(-0.5, 0.5, 11, dtype=np.float32)
    next_obs = obs[::-1].copy()
    for _ in range(8):
        model.replay_buffer.add(
            obs[None],
            next_obs[None],
            np.array([[3]]),
            np.array([2.0]),
            np.array([False]),
            [{"plant_observations": None}],
        )
    from stable_baselines3.common.logger import configure

    model.set_logger(configure(str(tmp_path), []))
    low, high = config.q_target_bounds
    with torch.no_grad():
        s, s2 = torch.as_tensor(obs[None]), torch.as_tensor(next_obs[None])
        target = (2.0 + config.learner.gamma * model.q_net_target(s2).max(dim=1, keepdim=True)[0]).clamp(low, high)
        expected = F.smooth_l1_loss(model.q_net(s)[:, 3:4], target).item()
        q_before = model.q_net(s)[0, 3].item()
    model.train(gradient_steps=1, batch_size=4)
    assert model.logger.name_to_value["train/loss"] == pytest.approx(expected, rel=1e-5)
    with torch.no_grad():
        q_after = model.q_net(s)[0, 3].item()
    assert abs(q_after - target.item()) < abs(q_before - target.item())  # one step towards the target


def test_clipped_targets_stay_within_the_return_bounds(tmp_path):
    config = DQNConfig(episode_s=0.4, learning_starts=0, learner=DQNLearner(clip_q_targets=True))
    low, high = config.q_target_bounds
    # an agent step's reward lies in action_repeat * [-1, 2] (shaping in [-1, 1] plus a bonus up to 1)
    assert (low, high) == pytest.approx((-4.0 / (1 - config.learner.gamma), 8.0 / (1 - config.learner.gamma)))
    assert agent_class(config) is TargetDQN and agent_class(DQNConfig()) is DQN
    model = build_dqn(config, make_training_env(config), seed=0, episodes=1)
    assert model.q_target_bounds == pytest.approx((low, high))
    with torch.no_grad():
        for layer in model.q_net_target.modules():  # a target network that values every action at 1e4
            if isinstance(layer, torch.nn.Linear):
                layer.weight.zero_()
                layer.bias.fill_(1e4)
    next_obs = torch.zeros(3, 11)
    rewards = torch.tensor([[1.0], [-1e5], [2.0]])
    dones = torch.tensor([[0.0], [1.0], [1.0]])
    targets = model.td_targets(rewards, dones, config.learner.gamma, next_obs)
    np.testing.assert_allclose(targets.numpy(), [[high], [low], [2.0]], rtol=1e-6)
    # without bounds the target is stable-baselines3's r + gamma * max_a Q_target(s', a)
    model.q_target_bounds = None
    np.testing.assert_allclose(
        model.td_targets(rewards, dones, config.learner.gamma, next_obs).numpy(),
        [[1.0 + config.learner.gamma * 1e4], [-1e5], [2.0]],
        rtol=1e-6,
    )
    with pytest.raises(ValueError, match="q_target_bounds"):
        TargetDQN("MlpPolicy", make_training_env(config), q_target_bounds=(1.0, -1.0))
    # the bounds survive saving and loading
    model.q_target_bounds = (low, high)
    model.save(tmp_path / "agent.zip")
    assert TargetDQN.load(tmp_path / "agent.zip", device="cpu").q_target_bounds == pytest.approx((low, high))

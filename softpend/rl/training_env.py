"""The training environment of DQN and DQN-MBPO, and the matching evaluation controller."""

from __future__ import annotations

from typing import Any, Callable, Optional

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import TimeLimit

from softpend.checks import positive_int
from softpend.envs import SoftPendulumDiscreteEnv, SoftPendulumEnv
from softpend.envs.randomised import RandomisedRod
from softpend.evaluation import GymPolicyController
from softpend.rl.config import DQNConfig


class ActionRepeat(gym.Wrapper):
    """Hold each action for ``repeat`` plant steps; the reward is the sum over those steps."""

    def __init__(self, env: gym.Env, repeat: int) -> None:
        super().__init__(env)
        self.repeat = positive_int("repeat", repeat)

    def step(self, action: Any):
        base = self.env.unwrapped
        assert isinstance(base, SoftPendulumEnv)  # make_training_env wraps a SoftPendulumDiscreteEnv
        observations = [base.report_observation.as_array()]
        total = 0.0
        for _ in range(self.repeat):
            obs, reward, terminated, truncated, info = self.env.step(action)
            total += float(reward)
            if "truncation_reason" in info:
                break
            observations.append(base.report_observation.as_array())
            if terminated or truncated:
                break
        info = dict(info, plant_observations=np.array(observations), plant_steps=len(observations) - 1)
        return obs, total, terminated, truncated, info


def make_base_env(config: DQNConfig, start: Optional[str] = None) -> SoftPendulumDiscreteEnv:
    """The discrete-torque environment of ``config.task`` with the config's torque levels (``start``
    overrides the task's start distribution)."""
    task = config.task if start is None else config.task.replace(start=start)
    return SoftPendulumDiscreteEnv(n_torque_levels=config.n_torque_levels, **task.env_kwargs())


def make_training_env(config: DQNConfig) -> gym.Env:
    """``TimeLimit(ActionRepeat(SoftPendulumDiscreteEnv(start=config.training_start)), episode_agent_steps)``, the
    environment inside :class:`~softpend.envs.randomised.RandomisedRod` when ``config.rod_uncertainty`` is set."""
    env: gym.Env = make_base_env(config, config.training_start)
    if config.rod_uncertainty is not None:
        env = RandomisedRod(env, config.task, config.rod_uncertainty)
    return TimeLimit(ActionRepeat(env, config.action_repeat), config.episode_agent_steps)


class HeldActionController(GymPolicyController):
    """:class:`~softpend.evaluation.GymPolicyController` that queries the policy every ``repeat`` plant steps and
    holds the torque in between."""

    _held_action: Any

    def __init__(self, predict: Callable[[np.ndarray], Any], env: Any, repeat: int) -> None:
        super().__init__(self._held_predict, env)
        self.repeat, self._inner_predict = positive_int("repeat", repeat), predict
        self.reset()

    def _held_predict(self, vector: np.ndarray) -> Any:
        if self._step % self.repeat == 0 or self._held_action is None:
            self._held_action = self._inner_predict(vector)
        self._step += 1
        return self._held_action

    def reset(self) -> None:
        super().reset()
        self._step, self._held_action = 0, None


def greedy_predictor(model: Any) -> Callable[[np.ndarray], Any]:
    """The greedy action of a stable-baselines3 DQN model for one observation vector or a batch of them:
    ``model.predict(vectors, deterministic=True)[0]`` without its per-call overhead."""
    import torch

    q_net = model.q_net

    def predict(vectors: np.ndarray) -> Any:
        x = torch.as_tensor(np.asarray(vectors), dtype=torch.float32)
        with torch.no_grad():
            actions = q_net(x.reshape(1, -1) if x.ndim == 1 else x).argmax(dim=1).numpy()
        return actions[0] if x.ndim == 1 else actions

    return predict


def policy_controller(model: Any, config: DQNConfig) -> HeldActionController:
    """Controller for :func:`softpend.evaluation.evaluate_controller` from a stable-baselines3 DQN model (its
    greedy actions, :func:`greedy_predictor`)."""
    return HeldActionController(greedy_predictor(model), make_base_env(config), config.action_repeat)

"""The training environment of DQN and DQN-MBPO, and the matching evaluation controller."""

from __future__ import annotations

from typing import Any, Callable, Optional

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import TimeLimit

from softpend.checks import positive_int
from softpend.envs import SoftPendulumDiscreteEnv, SoftPendulumEnv
from softpend.envs.randomised import RandomisedRod
from softpend.envs.reward import next_bonus
from softpend.plant import Observation
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


class HeldActionController:
    """Runs a policy trained on a softpend Gymnasium environment (e.g. a stable-baselines3 model) as a controller:
    the observation vectors rebuilt as the environment builds them (the reward's bonus advancing exactly as its
    reward advances it), the policy queried every ``repeat`` plant steps and its torque held in between."""

    def __init__(self, predict: Callable[[np.ndarray], Any], env: Any, repeat: int = 1) -> None:
        self.predict, self.env = predict, env.unwrapped if hasattr(env, "unwrapped") else env
        self.repeat = positive_int("repeat", repeat)
        self.reset()

    def reset(self) -> None:
        self.bonus, self._step, self._held_action = 0.0, 0, None

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        env = self.env
        self.bonus = float(next_bonus(observation.theta_rad, self.bonus, env.dt_s, env.reward_params))
        if self._step % self.repeat == 0:
            self._held_action = self.predict(env.observation_vector(observation, self.bonus))
        self._step += 1
        return env.torque_from_action(self._held_action)


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

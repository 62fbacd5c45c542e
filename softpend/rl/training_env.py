"""The training environment of DQN and DQN-MBPO, and the matching evaluation controller.

:func:`make_training_env` wraps ``SoftPendulumDiscreteEnv`` (the registered ``softpend/SoftPendulumDiscrete-v0``
class) in :class:`ActionRepeat` and a ``TimeLimit`` of ``config.episode_s``; with the config's robustness
options, the environment first draws a new rod every episode (:class:`RandomisedRod`) and shows the agent a
late and noisy observation (:class:`RigObservation`), as a rig would.  :class:`HeldActionController` runs a
trained agent through the shared :func:`softpend.evaluation.evaluate_controller` with the same action repeat.
"""

from __future__ import annotations

from typing import Any, Callable, Optional

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import TimeLimit

import math

from softpend.checks import non_negative, positive_int
from softpend.envs import SoftPendulumDiscreteEnv
from softpend.evaluation import DelayLine, GymPolicyController
from softpend.plant import make_plant
from softpend.plant.randomisation import randomised_rod
from softpend.rl.config import DQNConfig

__all__ = ["ActionRepeat", "HeldActionController", "RandomisedRod", "RigObservation", "greedy_predictor", "make_base_env",
           "make_training_env", "policy_controller"]


class RandomisedRod(gym.Wrapper):
    """Domain randomisation: every episode runs on a new rod, :func:`softpend.plant.randomisation.randomised_rod`
    of the environment's nominal rod with ``spread``, drawn from the environment's ``np_random`` (so that the
    seed of ``reset`` decides the rods).  The torque levels follow the drawn torque limit: the agent's actions
    are fractions of what the motor really delivers."""

    def __init__(self, env: gym.Env, spread: float, plant: str = "prb") -> None:
        super().__init__(env)
        base = env.unwrapped
        randomised_rod(base.params, np.random.default_rng(0), spread)  # ValueError on a bad spread, up front
        self.spread = float(spread)
        self.nominal = base.params
        self._plant_name, self._dt_s, self._substeps = plant, base.plant.dt_s, base.plant.substeps

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict[str, Any]] = None):
        base = self.env.unwrapped
        if seed is not None:
            self.env.reset(seed=seed, options=options)  # seeds np_random; the episode starts below
        rod = randomised_rod(self.nominal, base.np_random, self.spread)
        base.params = rod
        base.plant = make_plant(self._plant_name, params=rod, dt_s=self._dt_s, substeps=self._substeps)
        base.torque_limit_nm = rod.torque_limit_nm
        if hasattr(base, "torque_levels_nm"):
            base.torque_levels_nm = np.linspace(-1.0, 1.0, base.n_torque_levels) * rod.torque_limit_nm
        return self.env.reset(options=options)


class RigObservation(gym.ObservationWrapper):
    """The observation a rig delivers: ``delay_steps`` plant steps late, with the hub and tip angles perturbed by
    Gaussian noise of ``noise_rad`` (each ``(cos, sin)`` pair of the observation vector rotated by its own draw
    from the environment's ``np_random``).  Rewards and the plant's own records stay those of the true state."""

    def __init__(self, env: gym.Env, delay_steps: int = 0, noise_rad: float = 0.0) -> None:
        super().__init__(env)
        self._late = DelayLine(delay_steps)
        self.delay_steps = self._late.delay_steps
        self.noise_rad = non_negative("noise_rad", noise_rad)

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict[str, Any]] = None):
        self._late.clear()
        return super().reset(seed=seed, options=options)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        seen = np.array(self._late.push(observation), dtype=observation.dtype, copy=True)
        if self.noise_rad > 0:
            rng = self.env.unwrapped.np_random
            for c in (0, 2):  # (cos phi, sin phi), (cos theta, sin theta)
                angle = math.atan2(float(seen[c + 1]), float(seen[c])) + float(rng.normal(0.0, self.noise_rad))
                seen[c], seen[c + 1] = math.cos(angle), math.sin(angle)
        return seen


class ActionRepeat(gym.Wrapper):
    """Hold each action for ``repeat`` plant steps; the reward is the sum over those steps.

    ``info["plant_observations"]`` is the ``(k + 1, 10)`` array of plant observations from before the
    action to after it (:data:`softpend.plant.OBSERVATION_NAMES` order), ``info["torque_nm"]`` the torque
    applied, ``info["plant_steps"] = k`` the plant steps simulated (``k < repeat`` only if the simulation
    diverged).  Model-based learning and the learning curves read these.
    """

    def __init__(self, env: gym.Env, repeat: int) -> None:
        super().__init__(env)
        self.repeat = positive_int("repeat", repeat)

    def step(self, action: Any):
        base = self.env.unwrapped
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
        info = dict(info)
        info["plant_observations"] = np.array(observations)
        info["plant_steps"] = len(observations) - 1
        return obs, total, terminated, truncated, info


def make_base_env(config: DQNConfig, start: Optional[str] = None) -> SoftPendulumDiscreteEnv:
    """The discrete-torque environment of ``config.task`` with the config's torque levels (``start``
    overrides the task's start distribution)."""
    task = config.task if start is None else config.task.replace(start=start)
    return SoftPendulumDiscreteEnv(n_torque_levels=config.n_torque_levels, **task.env_kwargs())


def make_training_env(config: DQNConfig) -> gym.Env:
    """``TimeLimit(ActionRepeat(SoftPendulumDiscreteEnv(start=config.training_start)), episode_agent_steps)``,
    the environment inside wrapped in :class:`RandomisedRod` when ``config.rod_randomisation > 0`` and in
    :class:`RigObservation` when ``config.observation_delay_steps`` or ``config.observation_noise_rad`` is set."""
    env: gym.Env = make_base_env(config, config.training_start)
    if config.rod_randomisation > 0:
        env = RandomisedRod(env, config.rod_randomisation, plant=config.task.plant)
    if config.observation_delay_steps > 0 or config.observation_noise_rad > 0:
        env = RigObservation(env, config.observation_delay_steps, config.observation_noise_rad)
    return TimeLimit(ActionRepeat(env, config.action_repeat), config.episode_agent_steps)


class HeldActionController(GymPolicyController):
    """:class:`~softpend.evaluation.GymPolicyController` that queries the policy every ``repeat`` plant steps
    and holds the torque in between (the reward's bonus state is still advanced every step, as in
    training)."""

    def __init__(self, predict: Callable[[np.ndarray], Any], env: Any, repeat: int) -> None:
        super().__init__(predict, env)
        self.repeat = positive_int("repeat", repeat)
        self._step = 0
        self._held_action: Any = None
        self._inner_predict = predict
        self.predict = self._held_predict

    def _held_predict(self, vector: np.ndarray) -> Any:
        if self._step % self.repeat == 0 or self._held_action is None:
            self._held_action = self._inner_predict(vector)
        self._step += 1
        return self._held_action

    def reset(self) -> None:
        super().reset()
        self._step = 0
        self._held_action = None


def greedy_predictor(model: Any) -> Callable[[np.ndarray], Any]:
    """The greedy action of a stable-baselines3 DQN model for one observation vector (an integer) or a batch
    of them (an integer array): ``model.predict(vectors, deterministic=True)[0]`` without its per-call
    bookkeeping (input checks, training-mode switches, tensor round trips), which costs more than the
    Q-network itself.  The same float32 forward pass and argmax, so the same actions.
    """
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

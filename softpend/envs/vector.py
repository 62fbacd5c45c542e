"""Gymnasium vector environments of the soft pendulum task on the batched torch chain: ``num_envs`` copies of
:class:`~softpend.envs.SoftPendulumEnv` (same observations, rewards, seeded starts), autoreset ``NEXT_STEP``."""

from __future__ import annotations

from typing import Any, Optional, Sequence

import gymnasium as gym
import numpy as np
import torch
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector.utils import batch_space
from gymnasium.vector.vector_env import AutoresetMode

from softpend import MAX_EPISODE_STEPS
from softpend.checks import int_at_least
from softpend.envs.reward import RewardParams, next_bonus, step_reward
from softpend.envs.soft_pendulum import (
    OBSERVATION_BOUND,
    TaskSettings,
    check_torque_levels,
    draw_start,
    observation_vector,
    reset_options,
)
from softpend.plant import OBSERVATION_NAMES, RodParams
from softpend.plant.batched import BatchedPRBChain, BatchedRodParams, stable_substeps

_THETA = OBSERVATION_NAMES.index("theta_rad")


class SoftPendulumVectorEnv(TaskSettings, gym.vector.VectorEnv):
    """``num_envs`` soft-pendulum environments stepped together (``Box(-1, 1, (1,))`` actions per rod) on the
    PRB chain; the arguments as :class:`~softpend.envs.SoftPendulumEnv` and the batched chain take them."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}
    render_mode = None

    def __init__(
        self,
        num_envs: int = 1,
        params: Optional[RodParams] = None,
        dt_s: float = 0.01,
        substeps: Optional[int] = None,
        integrator: str = "rk4",
        compiled: bool = False,
        reward_params: Optional[RewardParams] = None,
        start: str = "hanging",
        start_noise_rad: float = 0.05,
        max_episode_steps: int = MAX_EPISODE_STEPS,
    ) -> None:
        self.num_envs = int_at_least("num_envs", num_envs, 1)
        self.set_task(params, reward_params, start, start_noise_rad)
        self.max_episode_steps = int_at_least("max_episode_steps", max_episode_steps, 1)

        if integrator == "rk4":
            stable = stable_substeps(self.params, dt_s)
            if substeps is None:
                substeps = stable
            elif int_at_least("substeps", substeps, 1) < stable:
                raise ValueError(
                    f"substeps must be at least {stable} (RK4 diverges with fewer, see "
                    f"softpend.plant.batched.stable_substeps), got {substeps!r}"
                )
        nominal = BatchedRodParams.from_params(self.params, batch_size=self.num_envs)
        self.chain = BatchedPRBChain(nominal, dt_s=dt_s, substeps=substeps, integrator=integrator, compiled=compiled)
        self.dt_s = self.chain.dt_s

        self.single_action_space = spaces.Box(-1.0, 1.0, shape=(1,), dtype=np.float32)
        self.single_observation_space = spaces.Box(-OBSERVATION_BOUND, OBSERVATION_BOUND, dtype=np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)

        b, n = self.num_envs, self.chain.n_coordinates
        self._q = torch.zeros(b, n, dtype=torch.float64)
        self._qd = torch.zeros(b, n, dtype=torch.float64)
        self._bonus = np.zeros(b)
        self._steps = np.zeros(b, dtype=np.int64)
        self._autoreset = np.zeros(b, dtype=bool)
        self._observations: Optional[np.ndarray] = None
        self._rngs: list[Optional[np.random.Generator]] = [None] * b

    def joint_state(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(q, q_dot)`` of every rod, shape ``(num_envs, n + 1)`` (copies)."""
        return self._q.clone(), self._qd.clone()

    def torques_from_actions(self, actions: Any) -> np.ndarray:
        """Hub torques [N m] for actions ``(num_envs, 1)`` or ``(num_envs,)``."""
        a = np.asarray(actions, dtype=np.float64)
        if a.shape == (self.num_envs, 1):
            a = a[:, 0]
        if a.shape != (self.num_envs,):
            raise ValueError(f"actions must have shape ({self.num_envs}, 1), got {np.shape(actions)}")
        if not np.all(np.isfinite(a)):
            raise ValueError("actions must be finite")
        return np.clip(a, -1.0, 1.0) * self.torque_limit_nm

    def _draw_starts(
        self, indices: np.ndarray, start: str, exact: Optional[tuple[np.ndarray, np.ndarray]] = None
    ) -> np.ndarray:
        """Restart the rods ``indices`` (states drawn from their generators, or rows of ``exact``); the observations."""
        q = np.zeros((len(indices), self.chain.n_coordinates))
        qd = np.zeros_like(q)
        for row, i in enumerate(indices):
            q[row, 0], qd[row, 0] = draw_start(self._rngs[i], start, self.start_noise_rad)
        if exact is not None:
            q, qd = exact[0][indices], exact[1][indices]
        index = torch.as_tensor(indices)
        self._q[index] = torch.as_tensor(q)
        self._qd[index] = torch.as_tensor(qd)
        self._steps[indices] = 0
        self._autoreset[indices] = False
        observations = self._observe()
        theta = observations[indices, _THETA]
        self._bonus[indices] = next_bonus(theta, np.zeros(len(indices)), self.dt_s, self.reward_params)
        return observations

    def _observe(self) -> np.ndarray:
        with torch.no_grad():
            return self.chain.observations(self._q, self._qd).numpy()

    def reset(self, *, seed: Optional[int | Sequence[Optional[int]]] = None, options: Optional[dict[str, Any]] = None):
        """Reset every sub-environment, or those of ``options["reset_mask"]``; ``seed``: ``None`` (keep the
        generators), ``s`` (seeds ``s, s + 1, ...``) or one per sub-environment."""
        start, exact = reset_options(options, self.start, self.chain.n_coordinates, self.num_envs, ("reset_mask",))
        if seed is None:
            seeds: list[Optional[int]] = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(self.num_envs)]
            super().reset(seed=int(seed))
        else:
            seeds = list(seed)  # type: ignore[arg-type]  # a sequence: ints were taken above
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed must be an int or hold {self.num_envs} seeds, got {len(seeds)}")
        mask = (options or {}).get("reset_mask")
        mask = np.ones(self.num_envs, dtype=bool) if mask is None else np.asarray(mask)
        if mask.shape != (self.num_envs,) or mask.dtype != np.bool_ or not mask.any():
            raise ValueError(f"options['reset_mask'] must be a boolean array of shape ({self.num_envs},) with a True")
        indices = np.flatnonzero(mask)
        for i in indices:
            if seeds[i] is not None or self._rngs[i] is None:
                self._rngs[i] = seeding.np_random(seeds[i])[0]
        self._observations = observations = self._draw_starts(indices, start, exact)
        vectors = observation_vector(observations, self._bonus, self)
        return vectors, {"observation": observations.copy(), "_observation": mask.copy()}

    def step(self, actions):
        if self._observations is None:
            raise RuntimeError("call reset() before step()")
        torques = self.torques_from_actions(actions)
        resetting = self._autoreset.copy()
        q_old, qd_old = self._q, self._qd
        with torch.no_grad():
            q, qd = self.chain.step(q_old, qd_old, torch.from_numpy(torques))
        finite = (torch.isfinite(q).all(1) & torch.isfinite(qd).all(1)).numpy()
        diverged = ~finite & ~resetting
        if diverged.any():
            keep = torch.from_numpy(~finite)
            q = torch.where(keep[:, None], q_old, q)
            qd = torch.where(keep[:, None], qd_old, qd)
        self._q, self._qd = q.contiguous(), qd.contiguous()
        observations = self._observe()
        reward, bonus = step_reward(observations[:, _THETA], self._bonus, self.dt_s, self.reward_params)
        reward = np.where(diverged, 0.0, reward)
        self._bonus = np.where(diverged, self._bonus, bonus)
        self._steps += 1
        truncated = (self._steps >= self.max_episode_steps) | diverged
        terminated = np.zeros(self.num_envs, dtype=bool)
        info: dict[str, Any] = {"torque_nm": np.where(resetting, 0.0, torques), "_torque_nm": ~resetting}
        if diverged.any():
            info["truncation_reason"] = np.where(diverged, "simulation diverged: non-finite state", None)
            info["_truncation_reason"] = diverged.copy()
        if resetting.any():
            indices = np.flatnonzero(resetting)
            observations[indices] = self._draw_starts(indices, self.start)[indices]
            reward[indices] = 0.0
            truncated[indices] = False
        self._autoreset = truncated | terminated
        self._observations = observations
        info["observation"] = observations.copy()
        info["_observation"] = np.ones(self.num_envs, dtype=bool)
        vectors = observation_vector(observations, self._bonus, self)
        return vectors, np.asarray(reward, dtype=np.float64), terminated, truncated, info


class SoftPendulumDiscreteVectorEnv(SoftPendulumVectorEnv):
    """:class:`SoftPendulumVectorEnv` with the actions of :class:`~softpend.envs.SoftPendulumDiscreteEnv`."""

    def __init__(self, num_envs: int = 1, n_torque_levels: int = 5, **kwargs: Any) -> None:
        n_torque_levels = check_torque_levels(n_torque_levels)
        super().__init__(num_envs=num_envs, **kwargs)
        self.n_torque_levels = n_torque_levels
        self._levels = np.linspace(-1.0, 1.0, n_torque_levels)
        self.single_action_space = spaces.Discrete(n_torque_levels)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

    def torques_from_actions(self, actions: Any) -> np.ndarray:
        """Hub torques [N m] for integer actions of shape ``(num_envs,)`` in ``[0, n_torque_levels)``."""
        a = np.asarray(actions)
        if a.shape != (self.num_envs,) or a.dtype.kind not in "iu":
            raise ValueError(f"actions must be integers of shape ({self.num_envs},), got {a.dtype} {a.shape}")
        if a.min() < 0 or a.max() >= self.n_torque_levels:
            raise ValueError(f"actions must lie in [0, {self.n_torque_levels}), got {a.min()}..{a.max()}")
        return self._levels[a] * self.torque_limit_nm

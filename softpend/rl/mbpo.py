"""DQN-MBPO: DQN trained on real transitions and on short rollouts of a learned dynamics ensemble."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3 import DQN
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import ReplayBufferSamples

from softpend.checks import in_unit_interval
from softpend.envs import step_reward
from softpend.envs.soft_pendulum import observation_vector
from softpend.io.arrays import read_npz
from softpend.plant import OBSERVATION_NAMES
from softpend.rl.config import MBPOConfig
from softpend.rl.dqn import run_training
from softpend.rl.training_env import make_base_env
from softpend.rl.training_log import TrainingLog

if TYPE_CHECKING:
    from softpend.sysid.model import DynamicsEnsemble, DynamicsModel

_THETA = OBSERVATION_NAMES.index("theta_rad")


class MBPOReplayBuffer(ReplayBuffer):
    """Replay buffer with a real part (this buffer, as stable-baselines3 fills it) and a model part."""

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: Any = "cpu",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        model_buffer_size: int = 60_000,
        real_ratio: float = 0.1,
    ) -> None:
        if n_envs != 1:
            raise ValueError(f"n_envs must be 1 for MBPOReplayBuffer, got {n_envs}")
        self.real_ratio, spaces_ = in_unit_interval("real_ratio", real_ratio), (observation_space, action_space)
        super().__init__(buffer_size, *spaces_, device=device, handle_timeout_termination=handle_timeout_termination)
        self.plant_observations = np.zeros((self.buffer_size, len(OBSERVATION_NAMES)), dtype=np.float64)
        self.model_buffer = ReplayBuffer(model_buffer_size, *spaces_, device=device, handle_timeout_termination=False)

    def add(self, obs, next_obs, action, reward, done, infos) -> None:  # noqa: D102 (SB3 API)
        self.plant_observations[self.pos] = infos[0]["plant_observations"][0]
        super().add(obs, next_obs, action, reward, done, infos)

    def add_model_transitions(
        self, obs: np.ndarray, next_obs: np.ndarray, actions: np.ndarray, rewards: np.ndarray
    ) -> None:
        """Append a batch of model transitions (no terminal states) to the model part (FIFO)."""
        buf = self.model_buffer
        obs, next_obs, actions, rewards = (a[-buf.buffer_size :] for a in (obs, next_obs, actions, rewards))  # newest
        n = len(obs)
        index = (buf.pos + np.arange(n)) % buf.buffer_size
        buf.observations[index, 0], buf.next_observations[index, 0] = obs, next_obs
        buf.actions[index, 0], buf.rewards[index, 0], buf.dones[index, 0] = actions.reshape(n, -1), rewards, 0.0
        if buf.pos + n >= buf.buffer_size:
            buf.full = True
        buf.pos = int((buf.pos + n) % buf.buffer_size)

    def real_observation_box(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-component ``(low, high)`` of the real observation vectors, widened by a tenth of the range."""
        both = np.concatenate([self.observations[: self.size(), 0], self.next_observations[: self.size(), 0]])
        low, high = both.min(axis=0), both.max(axis=0)
        return low - 0.1 * (high - low), high + 0.1 * (high - low)

    def sample(self, batch_size: int, env: Any = None) -> ReplayBufferSamples:
        n_real = batch_size if self.model_buffer.size() == 0 else int(round(self.real_ratio * batch_size))
        parts = []
        if n_real > 0:
            parts.append(super().sample(n_real, env=env))
        if batch_size - n_real > 0:
            parts.append(self.model_buffer.sample(batch_size - n_real, env=env))
        if len(parts) == 1:
            return parts[0]
        # field by field: tensors, and None for an optional field both buffers leave out (discounts)
        merged: list[Any] = [None if a is None or b is None else torch.cat([a, b]) for a, b in zip(parts[0], parts[1])]
        return ReplayBufferSamples(*merged)


class MBPOTrainer:
    """The model-based part of DQN-MBPO: real-episode store, model refits and model rollouts."""

    def __init__(self, config: MBPOConfig, seed: int, run_dir: Path, progress: bool = False) -> None:
        self.config, self.seed, self.run_dir, self.progress = config, int(seed), Path(run_dir), progress
        self.env = make_base_env(config)
        self.rng = np.random.default_rng([self.seed, 1])
        # draws of the training episodes' start distribution, for rollouts branched from start states
        self.start_env = make_base_env(config, config.training_start)
        self.start_env.reset(seed=self.seed * 1_000_003 + 17)
        self.generator = torch.Generator().manual_seed(self.seed * 7919 + 1)
        self.trials_observations: list[np.ndarray] = []
        self.trials_torques: list[np.ndarray] = []
        self.dynamics: Optional[DynamicsModel | DynamicsEnsemble] = None
        self.n_fits = self.model_steps = 0

    def dqn_kwargs(self) -> dict[str, Any]:
        """The arguments of DQN-MBPO's agent beyond DQN's: the MBPO buffer, learning after the random episodes."""
        c = self.config
        buffer_kwargs = {"model_buffer_size": c.rollout.buffer_size, "real_ratio": c.rollout.real_ratio}
        learning_starts = max(c.learning_starts, c.initial_random_episodes * c.episode_agent_steps)
        return dict(
            replay_buffer_class=MBPOReplayBuffer, replay_buffer_kwargs=buffer_kwargs, learning_starts=learning_starts
        )

    def add_episode(self, observations: np.ndarray, torques_nm: np.ndarray) -> None:
        """Store one real episode (plant observations (N, 10), torques (N - 1,))."""
        expected = self.config.episode_agent_steps * self.config.action_repeat + 1
        if len(observations) == expected:  # a diverged (shortened) episode is left out of the dataset
            self.trials_observations.append(np.asarray(observations, dtype=np.float64))
            self.trials_torques.append(np.asarray(torques_nm, dtype=np.float64))

    def dataset(self):
        """All stored real episodes as a :class:`softpend.sysid.TrajectoryDataset` (written to the run folder)."""
        from softpend.sysid import save_dataset

        obs = np.stack(self.trials_observations)
        p = 5  # positions then velocities in OBSERVATION_NAMES order
        meta: dict[str, Any] = dict(dt_s=self.config.dt_s, position_names=OBSERVATION_NAMES[:p], source="simulation")
        meta |= dict(plant=self.config.task.plant, plant_params=self.env.params, seed=self.seed)
        meta |= dict(protocol={"kind": "dqn-mbpo training episodes"}, notes="real plant episodes of a DQN-MBPO run")
        meta["differentiation"] = "exact (simulator velocities, as the environment observes them)"
        arrays = (obs[:, :, :p], obs[:, :, p:], np.stack(self.trials_torques))
        return save_dataset(self.run_dir / "real_data.npz", *arrays, **meta)

    def refit(self) -> None:
        """Refit the dynamics ensemble from scratch on all real episodes so far."""
        from softpend.sysid import TrainConfig, fit_dynamics_model, save_model

        if len(self.trials_observations) < 2:
            raise ValueError("need at least 2 complete real episodes to fit the dynamics model")
        c = self.config
        n_transitions = sum(len(t) for t in self.trials_torques)
        epochs = max(3, math.ceil(c.model.fit_steps * c.model.batch_size / n_transitions))
        fixed: dict[str, Any] = dict(information="full", limit_tip_reach=False, learning_rate=3e-3)
        sizes: dict[str, Any] = dict(hidden_widths=c.model.hidden_widths, ensemble_size=c.model.ensemble_size)
        schedule: dict[str, Any] = dict(max_epochs=epochs, patience=max(3, epochs // 4), batch_size=c.model.batch_size)
        train = TrainConfig(**fixed, **sizes, **schedule, seed=self.seed * 1000 + self.n_fits)
        result = fit_dynamics_model(self.dataset(), train, progress=self.progress)
        self.dynamics = result.model.eval()
        self.n_fits += 1
        fits = {"fits": self.n_fits, "episodes": len(self.trials_observations)}
        save_model(self.run_dir / "dynamics", self.dynamics, fits)

    @torch.no_grad()
    def rollouts(self, agent: DQN, buffer: MBPOReplayBuffer, n_rollouts: int, length: int, epsilon: float) -> int:
        """Branch ``n_rollouts`` model rollouts of ``length`` agent steps into the model buffer; transitions added."""
        if self.dynamics is None or buffer.size() == 0:
            return 0
        c, env = self.config, self.env
        index = self.rng.integers(0, buffer.size(), size=n_rollouts)  # real states: plant observations, env vectors
        raw, vec = buffer.plant_observations[index].copy(), buffer.observations[index, 0].copy()
        for i in range(int(round(c.rollout.start_branch_fraction * n_rollouts))):  # the first rows
            vec[i], info = self.start_env.reset()
            raw[i] = info["observation"]
        box = buffer.real_observation_box() if c.rollout.within_data else None
        bonus = vec[:, -1].astype(np.float64)
        levels = env.torque_levels_nm
        state = torch.as_tensor(raw, dtype=torch.float32)
        added, alive = 0, np.ones(n_rollouts, dtype=bool)
        for _ in range(length):
            actions = agent.q_net(torch.as_tensor(vec, dtype=torch.float32)).argmax(dim=1).numpy()
            explore = self.rng.random(len(actions)) < epsilon
            actions[explore] = self.rng.integers(0, len(levels), size=int(explore.sum()))
            torque = torch.as_tensor(levels[actions], dtype=torch.float32)
            reward = np.zeros(len(actions))
            for _ in range(c.action_repeat):
                state = self.dynamics.predict_next(state, torque, generator=self.generator)
                r, bonus = step_reward(state[:, _THETA].double().numpy(), bonus, c.dt_s, env.reward_params)
                reward += r
            plant = state.double().numpy()
            finite = np.all(np.isfinite(plant), axis=1) & np.isfinite(reward)
            plant[~finite] = 0.0
            next_vec = observation_vector(plant, np.asarray(bonus), env)
            inside = finite if box is None else finite & np.all((next_vec >= box[0]) & (next_vec <= box[1]), axis=1)
            alive &= inside
            if not alive.any():
                break
            buffer.add_model_transitions(vec[alive], next_vec[alive], actions[alive], reward[alive])
            added += int(alive.sum())
            vec = next_vec
            state = torch.as_tensor(plant, dtype=torch.float32)
        self.model_steps += added
        return added

    def before_step(self, agent: DQN, log: TrainingLog) -> None:
        """Every ``rollout.every_steps`` real agent steps, once the model is fitted, branch ``per_real_step *
        every_steps`` epsilon-greedy model rollouts of the scheduled length into the agent's model buffer."""
        c = self.config.rollout
        if agent.num_timesteps % c.every_steps == 0 and self.dynamics is not None:
            assert isinstance(agent.replay_buffer, MBPOReplayBuffer)
            n_rollouts, length = c.per_real_step * c.every_steps, c.length(log.n_episodes)
            self.rollouts(agent, agent.replay_buffer, n_rollouts, length, agent.exploration_rate)

    def episode_ended(self, observations: np.ndarray, torques_nm: np.ndarray, n_episodes: int) -> None:
        """Store the real episode; refit the dynamics ensemble after ``initial_random_episodes`` episodes and
        every ``model.refit_every_episodes`` after those."""
        self.add_episode(observations, torques_nm)
        after = n_episodes - self.config.initial_random_episodes
        if after >= 0 and after % self.config.model.refit_every_episodes == 0:
            self.refit()

    def callbacks(self, recorder: Any) -> tuple[list[BaseCallback], list[BaseCallback]]:
        """The callbacks before and after the episode bookkeeping (:class:`softpend.rl.dqn.EpisodeRecorder`)."""
        return [ModelRollouts(self, recorder.log)], [ModelRefit(self, recorder)]

    def save(self, folder: Path) -> None:
        """Write the real episodes and the counters into a checkpoint folder (the model is refitted on resume)."""
        counters = np.array([self.n_fits, self.model_steps])
        observations, torques = np.array(self.trials_observations), np.array(self.trials_torques)
        np.savez(folder / "mbpo_state.npz", observations=observations, torques=torques, counters=counters)

    def restore(self, folder: Path) -> None:
        """Inverse of :meth:`save`; refits the model on the restored episodes."""
        path = folder / "mbpo_state.npz"
        data = read_npz(path, "MBPO checkpoint")  # a regular file of plain arrays, read with a bound
        try:
            observations, torques, counters = data["observations"], data["torques"], data["counters"]
        except KeyError as exc:
            raise ValueError(f"{path}: not an MBPO checkpoint (no {exc} array)") from None
        steps = self.config.episode_agent_steps * self.config.action_repeat
        n = len(observations)
        shapes = not n or (observations.shape == (n, steps + 1, len(OBSERVATION_NAMES)) and torques.shape == (n, steps))
        counted = counters.shape == (2,) and counters.dtype.kind in "iu"
        if not (observations.dtype == torques.dtype == np.float64 and counted and shapes):
            raise ValueError(
                f"{path}: its arrays do not match the run's episodes ({observations.shape}, {torques.shape}, "
                f"{counters.shape})"
            )
        self.trials_observations, self.trials_torques = list(observations), list(torques)
        self.n_fits, self.model_steps = (int(v) for v in counters)
        if len(self.trials_observations) >= 2:
            self.refit()


class ModelRollouts(BaseCallback):
    """Before the episode bookkeeping of every agent step: :meth:`MBPOTrainer.before_step`, the model rollouts."""

    model: DQN

    def __init__(self, trainer: MBPOTrainer, log: TrainingLog) -> None:
        super().__init__()
        self.trainer, self.log = trainer, log

    def _on_step(self) -> bool:
        self.trainer.before_step(self.model, self.log)
        return True


class ModelRefit(BaseCallback):
    """After the episode bookkeeping, at an episode end: :meth:`MBPOTrainer.episode_ended`, the real episode stored
    and the dynamics ensemble refitted when due."""

    def __init__(self, trainer: MBPOTrainer, recorder: Any) -> None:
        super().__init__()
        self.trainer, self.recorder = trainer, recorder

    def _on_step(self) -> bool:
        if self.recorder.ended is not None:
            observations, torques_nm = self.recorder.ended
            self.trainer.episode_ended(observations, torques_nm, self.recorder.log.n_episodes)
        return True


def train_mbpo(
    config: MBPOConfig, seed: int, episodes: int, run_dir: Path | str, resume: bool = False, progress: bool = True
) -> tuple[DQN, TrainingLog]:
    """Train DQN-MBPO for ``episodes`` real training episodes (see the module docstring; arguments as
    :func:`softpend.rl.dqn.train_dqn`)."""
    if not isinstance(config, MBPOConfig):
        raise ValueError(f"config must be an MBPOConfig, got {type(config).__name__}")
    trainer = MBPOTrainer(config, seed, Path(run_dir), progress=False)
    return run_training("mbpo", config, seed, episodes, run_dir, resume, progress, part=trainer)

"""The settings of DQN and DQN-MBPO."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

from softpend.checks import (
    boolean,
    in_range,
    in_unit_interval,
    instance_of,
    int_at_least,
    one_of,
    positive,
    positive_ints,
    seed_tuple,
    set_ints,
)
from softpend.envs.randomised import RodUncertainty, optional_uncertainty
from softpend.evaluation import SUCCESS_STD_RAD, TEST_EPISODE_S
from softpend.io.outputs import atomic_write
from softpend.io.overrides import dataclass_from_data
from softpend.io.reading import MAX_CONFIG_BYTES, read_json_checked
from softpend.task import Task

#: The stable-baselines3 ``DQN`` arguments that are :class:`DQNLearner` fields of the same name.
SB3_FIELDS = (
    "learning_rate buffer_size batch_size gamma train_freq gradient_steps target_update_interval "
    "exploration_fraction exploration_initial_eps exploration_final_eps max_grad_norm"
).split()


@dataclass(frozen=True)
class DQNLearner:
    """The Q-learner: stable-baselines3 ``DQN`` arguments, the network's hidden layer widths, target clipping."""

    learning_rate: float = 1e-4
    buffer_size: int = 100_000
    batch_size: int = 32
    gamma: float = 0.99
    train_freq: int = 1
    gradient_steps: int = 1
    target_update_interval: int = 10_000
    exploration_fraction: float = 0.1
    exploration_initial_eps: float = 1.0
    exploration_final_eps: float = 0.05
    max_grad_norm: float = 10.0
    net_arch: tuple[int, ...] = (64, 64)
    clip_q_targets: bool = False

    def __post_init__(self) -> None:
        set_ints(self, "buffer_size batch_size train_freq gradient_steps target_update_interval", 1, "learner.")
        for name in ("learning_rate", "max_grad_norm"):
            positive(f"learner.{name}", getattr(self, name))
        in_range("learner.learning_rate", self.learning_rate, 1e-12, 1e30)  # Adam's step stays a float32
        for name in ("gamma", "exploration_fraction", "exploration_initial_eps", "exploration_final_eps"):
            in_unit_interval(f"learner.{name}", getattr(self, name))
        boolean("learner.clip_q_targets", self.clip_q_targets)
        object.__setattr__(self, "net_arch", positive_ints("learner.net_arch", self.net_arch))


@dataclass(frozen=True)
class StopRule:
    """Stop training after ``after_balanced_evaluations`` balanced evaluations in a row (0: never), each start
    within ``upright_std_rad``, confirmed on ``confirm_seeds`` with at most ``confirm_max_failures`` failures."""

    after_balanced_evaluations: int = 0
    upright_std_rad: float = 0.1
    confirm_seeds: tuple[int, ...] = ()
    confirm_max_failures: int = 0

    def __post_init__(self) -> None:
        set_ints(self, "after_balanced_evaluations confirm_max_failures", 0, "stop.")
        positive("stop.upright_std_rad", self.upright_std_rad)
        confirm = seed_tuple("stop.confirm_seeds", self.confirm_seeds)
        if confirm and self.confirm_max_failures >= len(confirm):
            raise ValueError(
                f"stop.confirm_max_failures ({self.confirm_max_failures}) must be less than the {len(confirm)} "
                "stop.confirm_seeds: a confirmation needs a start that balances"
            )
        object.__setattr__(self, "confirm_seeds", confirm)


@dataclass(frozen=True)
class DQNConfig:
    """Model-free DQN on ``SoftPendulumDiscreteEnv``; with ``rod_uncertainty`` each training episode runs on a rod
    drawn around ``task.rod`` (:class:`~softpend.envs.randomised.RandomisedRod`)."""

    task: Task = field(default_factory=Task)
    n_torque_levels: int = 5
    episode_s: float = 5.0
    action_repeat: int = 4
    training_start: str = "hanging"
    learning_starts: int = 100
    reset_every_episodes: int = 0
    checkpoint_every_episodes: int = 10
    eval_every_episodes: int = 1
    eval_seeds: tuple[int, ...] = tuple(range(1000, 1008))
    eval_until_first_failure: bool = True
    eval_duration_s: float = TEST_EPISODE_S
    learner: DQNLearner = field(default_factory=DQNLearner)
    stop: StopRule = field(default_factory=StopRule)
    rod_uncertainty: Optional[RodUncertainty] = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "rod_uncertainty", optional_uncertainty(self.rod_uncertainty))
        for f in dataclasses.fields(self):
            if isinstance(f.default_factory, type):  # task and the settings groups
                instance_of(f.name, getattr(self, f.name), f.default_factory)
        set_ints(self, "n_torque_levels action_repeat eval_every_episodes checkpoint_every_episodes", 1)
        set_ints(self, "learning_starts reset_every_episodes", 0)
        int_at_least("n_torque_levels", self.n_torque_levels, 2)
        one_of("training_start", self.training_start, ("random", "hanging", "upright"))
        boolean("eval_until_first_failure", self.eval_until_first_failure)
        for name in ("episode_s", "eval_duration_s"):
            positive(name, getattr(self, name))
        if self.eval_until_first_failure and self.stop.upright_std_rad > SUCCESS_STD_RAD:
            raise ValueError(
                f"stop.upright_std_rad ({self.stop.upright_std_rad!r}) must be at most the success level "
                f"{SUCCESS_STD_RAD:g} rad with eval_until_first_failure (a balanced evaluation must run every start)"
            )
        seeds = seed_tuple("eval_seeds", self.eval_seeds, non_empty=True)
        shared = set(self.stop.confirm_seeds) & set(seeds)
        if shared:
            raise ValueError(
                f"stop.confirm_seeds {sorted(shared)} are also eval_seeds: a confirmation needs starts of its own"
            )
        if self.episode_s < self.agent_dt_s * (1 - 1e-9):
            raise ValueError(
                f"episode_s ({self.episode_s!r} s) must be at least one agent step, action_repeat x task.dt_s = "
                f"{self.agent_dt_s:g} s"
            )
        if self.episode_agent_steps % self.learner.train_freq:
            raise ValueError(
                f"learner.train_freq ({self.learner.train_freq}) must divide the agent steps of an episode "
                f"({self.episode_agent_steps}), so that a run ends exactly at an episode boundary"
            )
        object.__setattr__(self, "eval_seeds", seeds)

    @property
    def selection_seeds(self) -> tuple[int, ...]:
        """``eval_seeds`` and ``stop.confirm_seeds``."""
        return self.eval_seeds + self.stop.confirm_seeds

    @property
    def dt_s(self) -> float:
        """Plant step [s]."""
        return self.task.dt_s

    @property
    def agent_dt_s(self) -> float:
        """Time between agent decisions [s]."""
        return self.dt_s * self.action_repeat

    @property
    def q_target_bounds(self) -> tuple[float, float]:
        """``(low, high)``: the range of discounted returns [reward units] that the report's reward allows."""
        from softpend.envs.reward import RewardParams

        gamma = self.learner.gamma
        low, high = -1.0, 1.0 + RewardParams().bonus_weight
        scale = self.action_repeat / (1.0 - gamma) if gamma < 1.0 else math.inf
        return (low * scale, high * scale)

    @property
    def episode_agent_steps(self) -> int:
        """Agent steps per training episode."""
        return max(1, int(round(self.episode_s / self.agent_dt_s)))


@dataclass(frozen=True)
class ModelSettings:
    """DQN-MBPO's dynamics ensemble: its size and hidden widths, the fit's steps and batch, the refit period."""

    ensemble_size: int = 3
    hidden_widths: tuple[int, ...] = (64, 64)
    fit_steps: int = 1500
    batch_size: int = 256
    refit_every_episodes: int = 2

    def __post_init__(self) -> None:
        set_ints(self, "ensemble_size fit_steps batch_size refit_every_episodes", 1, "model.")
        object.__setattr__(self, "hidden_widths", positive_ints("model.hidden_widths", self.hidden_widths))


@dataclass(frozen=True)
class RolloutSettings:
    """DQN-MBPO's model rollouts: ``per_real_step * every_steps`` every ``every_steps`` real agent steps, of the
    ``schedule``'s length (first_episode, last_episode, min_length, max_length); ``real_ratio`` of each batch real;
    ``within_data``: rollouts stop outside the real data's box."""

    per_real_step: int = 9
    every_steps: int = 125
    schedule: tuple[int, int, int, int] = (3, 20, 1, 5)
    buffer_size: int = 60_000
    real_ratio: float = 0.5
    start_branch_fraction: float = 0.0
    within_data: bool = False

    def __post_init__(self) -> None:
        set_ints(self, "per_real_step every_steps buffer_size", 1, "rollout.")
        for name in ("real_ratio", "start_branch_fraction"):
            in_unit_interval(f"rollout.{name}", getattr(self, name))
        boolean("rollout.within_data", self.within_data)
        schedule = tuple(int(v) for v in self.schedule)
        if len(schedule) != 4 or schedule[0] < 0 or schedule[1] < schedule[0] or schedule[2] < 1 or schedule[3] < 1:
            raise ValueError(
                "rollout.schedule must be (first_episode >= 0, last_episode >= first_episode, min_length >= 1, "
                f"max_length >= 1), got {self.schedule!r}"
            )
        object.__setattr__(self, "schedule", schedule)

    def length(self, episode: int) -> int:
        """Rollout length (agent steps) at a training episode (mbrl-lib's linear schedule)."""
        first, last, low, high = self.schedule
        if episode <= first or episode >= last:
            return low if episode <= first else high
        return int(round(low + (episode - first) / (last - first) * (high - low)))


@dataclass(frozen=True)
class MBPOConfig(DQNConfig):
    """DQN-MBPO: DQN trained on short rollouts of a learned dynamics ensemble branched from real states."""

    initial_random_episodes: int = 3
    model: ModelSettings = field(default_factory=ModelSettings)
    rollout: RolloutSettings = field(default_factory=RolloutSettings)

    def __post_init__(self) -> None:
        super().__post_init__()
        set_ints(self, "initial_random_episodes", 1)


def config_to_dict(config: DQNConfig) -> dict[str, Any]:
    """The fields of ``config`` as plain JSON data, with its class name (``rod_uncertainty`` only when set)."""
    data = {"class": type(config).__name__, **dataclasses.asdict(config), "task": config.task.to_dict()}
    uncertainty, data = config.rod_uncertainty, {k: v for k, v in data.items() if k != "rod_uncertainty"}
    return data if uncertainty is None else data | {"rod_uncertainty": uncertainty.to_dict()}


def saved_config_data(config: DQNConfig) -> dict[str, Any]:
    """``config`` as :func:`save_config` saves it, read back as JSON data."""
    return json.loads(json.dumps(config_to_dict(config)))


def save_config(config: DQNConfig, path: Path) -> None:
    """Write ``config`` as JSON (with its class name)."""
    text = json.dumps(config_to_dict(config), indent=2)
    with atomic_write(path, "w") as handle:
        handle.write(text)


def load_config(path: Path) -> DQNConfig:
    """Read a config written by :func:`save_config`."""
    data = read_json_checked(path, "config file", MAX_CONFIG_BYTES)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a config (expected a JSON object, got {type(data).__name__})")
    name = data.pop("class", "DQNConfig")
    cls = {"DQNConfig": DQNConfig, "MBPOConfig": MBPOConfig}.get(name) if isinstance(name, str) else None
    if cls is None:
        raise ValueError(f"{path}: unknown config class")
    data.setdefault("rod_uncertainty", None)
    try:
        return dataclass_from_data(cls, data, path, task=Task.from_dict, rod_uncertainty=optional_uncertainty)
    except (TypeError, KeyError, AttributeError) as exc:
        raise ValueError(f"{path}: not a {cls.__name__}: {exc}") from exc

"""The settings of DQN and DQN-MBPO."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from softpend.checks import boolean, in_range, in_unit_interval, int_at_least, one_of, positive, positive_int
from softpend.evaluation import SUCCESS_STD_RAD, TEST_EPISODE_S
from softpend.io.outputs import atomic_write
from softpend.io.overrides import check_fields
from softpend.io.reading import MAX_CONFIG_BYTES, read_json_checked
from softpend.task import Task

__all__ = ["DQNConfig", "MBPOConfig", "SB3_FIELDS", "config_to_dict", "load_config", "saved_config_data", "save_config"]

#: The stable-baselines3 ``DQN`` arguments that are :class:`DQNConfig` fields of the same name.
SB3_FIELDS = (
    "learning_rate buffer_size learning_starts batch_size gamma train_freq gradient_steps target_update_interval "
    "exploration_fraction exploration_initial_eps exploration_final_eps max_grad_norm"
).split()


@dataclass(frozen=True)
class DQNConfig:
    """Model-free DQN on ``SoftPendulumDiscreteEnv``."""

    task: Task = field(default_factory=Task)
    n_torque_levels: int = 5
    episode_s: float = 5.0
    action_repeat: int = 4
    training_start: str = "hanging"
    learning_rate: float = 1e-4
    buffer_size: int = 100_000
    learning_starts: int = 100
    batch_size: int = 32
    gamma: float = 0.99
    train_freq: int = 1
    gradient_steps: int = 1
    target_update_interval: int = 10_000
    exploration_fraction: float = 0.1
    exploration_initial_eps: float = 1.0
    exploration_final_eps: float = 0.05
    max_grad_norm: float = 10.0
    clip_q_targets: bool = False
    net_arch: tuple[int, ...] = (64, 64)
    reset_every_episodes: int = 0
    eval_every_episodes: int = 1
    eval_seeds: tuple[int, ...] = tuple(range(1000, 1008))
    eval_until_first_failure: bool = True
    eval_duration_s: float = TEST_EPISODE_S
    checkpoint_every_episodes: int = 10
    stop_after_balanced_evaluations: int = 0
    stop_upright_std_rad: float = 0.1
    stop_confirm_seeds: tuple[int, ...] = ()
    stop_confirm_max_failures: int = 0

    def __post_init__(self) -> None:
        _set_ints(self, "n_torque_levels action_repeat buffer_size batch_size train_freq gradient_steps", 1)
        _set_ints(self, "target_update_interval eval_every_episodes checkpoint_every_episodes", 1)
        one_of("training_start", self.training_start, ("random", "hanging", "upright"))
        if not isinstance(self.task, Task):
            raise ValueError(f"task must be a Task, got {type(self.task).__name__}")
        boolean("clip_q_targets", self.clip_q_targets)
        boolean("eval_until_first_failure", self.eval_until_first_failure)
        int_at_least("n_torque_levels", self.n_torque_levels, 2)
        _set_ints(self, "learning_starts reset_every_episodes stop_after_balanced_evaluations", 0)
        for name in ("episode_s", "learning_rate", "eval_duration_s", "max_grad_norm", "stop_upright_std_rad"):
            positive(name, getattr(self, name))
        in_range("learning_rate", self.learning_rate, 1e-12, 1e30)  # Adam's step stays a float32
        if self.eval_until_first_failure and self.stop_upright_std_rad > SUCCESS_STD_RAD:
            raise ValueError(
                f"stop_upright_std_rad ({self.stop_upright_std_rad!r}) must be at most the success level "
                f"{SUCCESS_STD_RAD:g} rad with eval_until_first_failure (a balanced evaluation must run every start)"
            )
        for name in ("gamma", "exploration_fraction", "exploration_initial_eps", "exploration_final_eps"):
            in_unit_interval(name, getattr(self, name))
        object.__setattr__(self, "net_arch", _positive_ints("net_arch", self.net_arch))
        seeds = _seed_tuple("eval_seeds", self.eval_seeds)
        if len(seeds) == 0:
            raise ValueError("eval_seeds must not be empty")
        confirm = _seed_tuple("stop_confirm_seeds", self.stop_confirm_seeds)
        if set(confirm) & set(seeds):
            raise ValueError(
                f"stop_confirm_seeds {sorted(set(confirm) & set(seeds))} are also eval_seeds: a confirmation "
                "needs starts of its own"
            )
        object.__setattr__(self, "stop_confirm_seeds", confirm)
        failures = int_at_least("stop_confirm_max_failures", self.stop_confirm_max_failures, 0)
        if confirm and failures >= len(confirm):
            raise ValueError(
                f"stop_confirm_max_failures ({failures}) must be less than the {len(confirm)} "
                "stop_confirm_seeds: a confirmation needs a start that balances"
            )
        object.__setattr__(self, "stop_confirm_max_failures", failures)
        if self.episode_s < self.agent_dt_s * (1 - 1e-9):
            raise ValueError(
                f"episode_s ({self.episode_s!r} s) must be at least one agent step, action_repeat x task.dt_s = "
                f"{self.agent_dt_s:g} s"
            )
        if self.episode_agent_steps % self.train_freq:
            raise ValueError(
                f"train_freq ({self.train_freq}) must divide the agent steps of an episode ({self.episode_agent_steps}), "
                "so that a run ends exactly at an episode boundary"
            )
        object.__setattr__(self, "eval_seeds", seeds)

    @property
    def selection_seeds(self) -> tuple[int, ...]:
        """``eval_seeds`` and ``stop_confirm_seeds``."""
        return self.eval_seeds + self.stop_confirm_seeds

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

        low, high = -1.0, 1.0 + RewardParams().bonus_weight
        scale = self.action_repeat / (1.0 - self.gamma) if self.gamma < 1.0 else math.inf
        return (low * scale, high * scale)

    @property
    def episode_agent_steps(self) -> int:
        """Agent steps per training episode."""
        return max(1, int(round(self.episode_s / self.agent_dt_s)))


@dataclass(frozen=True)
class MBPOConfig(DQNConfig):
    """DQN-MBPO: DQN trained on short rollouts of a learned dynamics ensemble branched from real states."""

    rollouts_per_real_step: int = 9
    rollout_every_steps: int = 125
    rollout_schedule: tuple[int, int, int, int] = (3, 20, 1, 5)
    model_buffer_size: int = 60_000
    real_ratio: float = 0.5
    initial_random_episodes: int = 3
    model_refit_every_episodes: int = 2
    ensemble_size: int = 3
    model_fit_steps: int = 1500
    model_batch_size: int = 256
    model_hidden_widths: tuple[int, ...] = (64, 64)
    start_branch_fraction: float = 0.0
    rollouts_within_data: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        _set_ints(self, "rollouts_per_real_step rollout_every_steps model_buffer_size model_refit_every_episodes", 1)
        _set_ints(self, "ensemble_size model_fit_steps model_batch_size", 1)
        _set_ints(self, "initial_random_episodes", 1, at_least=True)
        for name in ("real_ratio", "start_branch_fraction"):
            in_unit_interval(name, getattr(self, name))
        boolean("rollouts_within_data", self.rollouts_within_data)
        schedule = tuple(int(v) for v in self.rollout_schedule)
        if len(schedule) != 4 or schedule[0] < 0 or schedule[1] < schedule[0] or schedule[2] < 1 or schedule[3] < 1:
            raise ValueError(
                "rollout_schedule must be (first_episode >= 0, last_episode >= first_episode, min_length >= 1, "
                f"max_length >= 1), got {self.rollout_schedule!r}"
            )
        object.__setattr__(self, "rollout_schedule", schedule)
        object.__setattr__(self, "model_hidden_widths", _positive_ints("model_hidden_widths", self.model_hidden_widths))

    def rollout_length(self, episode: int) -> int:
        """Rollout length (agent steps) at a training episode (mbrl-lib's linear schedule)."""
        first, last, low, high = self.rollout_schedule
        if episode <= first or last == first:
            return low if episode <= first else high
        if episode >= last:
            return high
        return int(round(low + (episode - first) / (last - first) * (high - low)))


def _positive_ints(name: str, value: Any) -> tuple[int, ...]:
    """``value`` as a non-empty tuple of positive ints, else ``ValueError`` naming ``name``."""
    try:
        widths = tuple(positive_int(name, w) for w in value)
    except (TypeError, ValueError):
        widths = ()
    if not widths:
        raise ValueError(f"{name} must be a non-empty tuple of positive integers, got {value!r}")
    return widths


def _seed_tuple(name: str, value: Any) -> tuple[int, ...]:
    """``value`` as a tuple of seeds (ints >= 0), else ``ValueError`` naming ``name``."""
    try:
        return tuple(int_at_least(name, s, 0) for s in value)
    except TypeError:
        raise ValueError(f"{name} must be a tuple of integers >= 0, got {value!r}") from None


def _set_ints(config: Any, names: str, low: int, at_least: bool = False) -> None:
    """Check and convert the int fields ``names`` (space-separated): ``>= low``, or positive when ``low`` is 1."""
    for name in names.split():
        value = getattr(config, name)
        checked = positive_int(name, value) if low == 1 and not at_least else int_at_least(name, value, low)
        object.__setattr__(config, name, checked)


def config_to_dict(config: DQNConfig) -> dict[str, Any]:
    """The fields of ``config`` as plain JSON data, with its class name."""
    data = dataclasses.asdict(config)
    data["task"] = config.task.to_dict()
    return {"class": type(config).__name__, **data}


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
    data = read_json_checked(path, "config file", MAX_CONFIG_BYTES)  # a regular file, read with a bound
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a config (expected a JSON object, got {type(data).__name__})")
    name = data.pop("class", "DQNConfig")
    cls = {"DQNConfig": DQNConfig, "MBPOConfig": MBPOConfig}.get(name) if isinstance(name, str) else None
    if cls is None:
        raise ValueError(f"{path}: unknown config class")
    check_fields(cls, data, path)
    try:
        task = Task.from_dict(data.pop("task"))
        fields: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items()}
        return cls(task=task, **fields)
    except (TypeError, KeyError, AttributeError) as exc:
        raise ValueError(f"{path}: not a {cls.__name__}: {exc}") from exc

"""State vectors of the learned dynamics models: full information (the ten observed variables) or limited (hub
angle, tip position and their differenced rates), each optionally followed by ``history`` past position frames
(lag 1 first).  The first ``2 P`` entries (positions, then velocities) are the core that the network predicts."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from softpend.checks import int_at_least, one_of
from softpend.sysid.dataset import TrajectoryDataset
from softpend.sysid.variables import POSITION_NAMES, is_angle, velocity_name

INFORMATION_LEVELS: tuple[str, ...] = ("full", "limited")
_LIMITED_POSITIONS: tuple[str, ...] = ("phi_rad", "ex_m", "ey_m")


@dataclass(frozen=True)
class StateLayout:
    """Which observed variables make up the model state, how many past frames, and whether the velocities are the
    dataset's differenced ones or (simulated data, full information) the simulator's true ones."""

    information: str = "full"
    history: int = 0
    velocity_source: str = "observed"

    def __post_init__(self) -> None:
        one_of("information", self.information, INFORMATION_LEVELS)
        object.__setattr__(self, "history", int_at_least("history", self.history, 0))
        one_of("velocity_source", self.velocity_source, ("observed", "true"))

    @classmethod
    def full(cls, history: int = 0, velocity_source: str = "observed") -> "StateLayout":
        """All observed variables (``d = 10 + 5 * history``)."""
        return cls("full", history, velocity_source)

    @classmethod
    def limited(cls, history: int = 0) -> "StateLayout":
        """Base angle and tip position, differenced velocities, ``history`` past frames."""
        return cls("limited", history, "observed")

    @property
    def position_names(self) -> tuple[str, ...]:
        """Position variables of the core state."""
        return POSITION_NAMES if self.information == "full" else _LIMITED_POSITIONS

    @property
    def n_positions(self) -> int:
        return len(self.position_names)

    @property
    def core_dim(self) -> int:
        """Positions plus velocities, ``2 P`` (what the network predicts)."""
        return 2 * self.n_positions

    @property
    def names(self) -> tuple[str, ...]:
        """Name of every entry of the state vector, in order."""
        core = self.position_names + tuple(velocity_name(n) for n in self.position_names)
        lags = tuple(f"{n}_lag{k}" for k in range(1, self.history + 1) for n in self.position_names)
        return core + lags

    @property
    def dim(self) -> int:
        return self.core_dim + self.history * self.n_positions

    @property
    def position_angle_mask(self) -> np.ndarray:
        """Which position variables are angles (wrapped), shape ``(P,)``."""
        return np.array([is_angle(n) for n in self.position_names])

    @property
    def angle_mask(self) -> np.ndarray:
        """Which state entries are wrapped angles, shape ``(d,)``."""
        pos = self.position_angle_mask
        return np.concatenate([pos, np.zeros(self.n_positions, bool), np.tile(pos, self.history)])

    def index(self, name: str) -> int:
        """Position of a variable in the state vector."""
        if name not in self.names:
            raise ValueError(f"name must be one of {self.names}, got {name!r}")
        return self.names.index(name)

    def states(self, dataset: TrajectoryDataset) -> np.ndarray:
        """State vectors of every trial, ``(T, N - history, d)``: sample ``i`` is the dataset's ``i + history``."""
        missing = [n for n in self.position_names if n not in dataset.position_names]
        if missing:
            raise ValueError(
                f"information={self.information!r} needs {list(self.position_names)} but the dataset lacks {missing}"
                + ("; use information='limited'" if self.information == "full" else "")
            )
        if dataset.n_samples < self.history + 2:
            raise ValueError(f"trials of {dataset.n_samples} samples are too short for history={self.history}")
        positions = np.stack([dataset.column(n) for n in self.position_names], axis=-1)
        column = dataset.true_column if self.velocity_source == "true" else dataset.column
        velocities = np.stack([column(velocity_name(n)) for n in self.position_names], axis=-1)
        h, n = self.history, dataset.n_samples
        parts = [positions[:, h:], velocities[:, h:]] + [positions[:, h - k : n - k] for k in range(1, h + 1)]
        return np.ascontiguousarray(np.concatenate(parts, axis=-1))

    def torques(self, dataset: TrajectoryDataset) -> np.ndarray:
        """Torques ``(T, N - history - 1)`` [N m] aligned with :meth:`states` (entry ``i`` acts from state ``i``)."""
        return np.ascontiguousarray(dataset.torques_nm[:, self.history :])

    def transitions(self, dataset: TrajectoryDataset, trials: np.ndarray | None = None) -> "TransitionData":
        """All ``(state, torque, next state)`` triples of the given trials (default: all), flattened."""
        trials = np.arange(dataset.n_trials) if trials is None else np.asarray(trials, dtype=np.int64)
        states, torques = self.states(dataset)[trials], self.torques(dataset)[trials].reshape(-1)
        return TransitionData(states[:, :-1].reshape(-1, self.dim), torques, states[:, 1:].reshape(-1, self.dim))


class TransitionData(NamedTuple):
    """Flattened one-step transitions: ``states`` and ``next_states`` ``(M, d)``, ``torques_nm`` ``(M,)``."""

    states: np.ndarray
    torques_nm: np.ndarray
    next_states: np.ndarray

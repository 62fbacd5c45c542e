"""State vectors of the learned dynamics models at the two information levels.

Full information (``StateLayout.full()``, ``d = 10``): every observed variable, in
:data:`softpend.plant.OBSERVATION_NAMES` order::

    [phi_rad, theta_rad, ex_m, ey_m, er_rad, phi_dot_rad_s, theta_dot_rad_s, ex_dot_m_s, ey_dot_m_s, er_dot_rad_s]

optionally followed by ``history`` past frames of the five positions (``StateLayout.full(history)``).

Limited information (``StateLayout.limited(history)``, ``d = 6 + 3 * history``): only the base angle and
the tip position, their backward-difference velocities, then ``history`` past frames of the positions
(lag 1 first)::

    [phi_rad, ex_m, ey_m, phi_dot_rad_s, ex_dot_m_s, ey_dot_m_s,
     phi_rad_lag1, ex_m_lag1, ey_m_lag1, ..., phi_rad_lag<h>, ex_m_lag<h>, ey_m_lag<h>]

Units are the report's: angles [rad] from upright, counter-clockwise positive, wrapped to ``[-pi, pi)``;
tip coordinates [m] relative to the hub axis, y up; rates [rad/s, m/s].  The first ``2 P`` entries
(positions then velocities, ``P`` position variables) are the *core* that the network predicts; lagged
frames are shifted in by :meth:`softpend.sysid.DynamicsModel.predict_next`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from softpend.sysid.dataset import TrajectoryDataset
from softpend.sysid.variables import POSITION_NAMES, is_angle, velocity_name

__all__ = ["INFORMATION_LEVELS", "StateLayout", "TransitionData"]

INFORMATION_LEVELS: tuple[str, ...] = ("full", "limited")
_LIMITED_POSITIONS: tuple[str, ...] = ("phi_rad", "ex_m", "ey_m")


@dataclass(frozen=True)
class StateLayout:
    """Which observed variables make up the model state, and how many past frames.

    Parameters
    ----------
    information : {"full", "limited"}
        Information level (see the module docstring).
    history : int
        Number of past position frames in the state (default 0).
    velocity_source : {"observed", "true"}
        Velocities from the dataset's ``velocities`` (backward differences, as a rig) or, for simulated
        data at full information, the simulator's true velocities.
    """

    information: str = "full"
    history: int = 0
    velocity_source: str = "observed"

    def __post_init__(self) -> None:
        if self.information not in INFORMATION_LEVELS:
            raise ValueError(f"information must be one of {INFORMATION_LEVELS}, got {self.information!r}")
        if isinstance(self.history, bool) or int(self.history) != self.history or self.history < 0:
            raise ValueError(f"history must be a non-negative integer, got {self.history!r}")
        object.__setattr__(self, "history", int(self.history))
        if self.velocity_source not in ("observed", "true"):
            raise ValueError(f"velocity_source must be 'observed' or 'true', got {self.velocity_source!r}")

    @classmethod
    def full(cls, history: int = 0, velocity_source: str = "observed") -> "StateLayout":
        """All observed variables (``d = 10 + 5 * history``)."""
        return cls("full", history, velocity_source)

    @classmethod
    def limited(cls, history: int = 0) -> "StateLayout":
        """Base angle and tip position, differenced velocities, ``history`` past frames."""
        return cls("limited", history, "observed")

    # ------------------------------------------------------------------ names and masks
    @property
    def position_names(self) -> tuple[str, ...]:
        """Position variables of the core state."""
        return POSITION_NAMES if self.information == "full" else _LIMITED_POSITIONS

    @property
    def n_positions(self) -> int:
        """Number of position variables ``P``."""
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
        """State dimension ``d``."""
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

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (for JSON metadata)."""
        return {"information": self.information, "history": self.history, "velocity_source": self.velocity_source}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "StateLayout":
        """Inverse of :meth:`to_dict`."""
        return cls(**data)

    # ------------------------------------------------------------------ from data
    def states(self, dataset: TrajectoryDataset) -> np.ndarray:
        """State vectors of every trial, shape ``(T, N - history, d)`` (sample ``i`` of the result is
        sample ``i + history`` of the dataset: the first ``history`` samples only feed the lags).

        Raises
        ------
        ValueError
            If the dataset lacks a variable of this layout, or (``velocity_source="true"``) has no true
            observations, or is shorter than ``history + 2`` samples.
        """
        missing = [n for n in self.position_names if n not in dataset.position_names]
        if missing:
            raise ValueError(
                f"information={self.information!r} needs {list(self.position_names)} but the dataset lacks {missing}"
                + ("; use information='limited'" if self.information == "full" else "")
            )
        if dataset.n_samples < self.history + 2:
            raise ValueError(
                f"dataset has {dataset.n_samples} samples a trial; history={self.history} needs at least {self.history + 2}"
            )
        positions = np.stack([dataset.column(n) for n in self.position_names], axis=-1)
        if self.velocity_source == "true":
            velocities = np.stack([dataset.true_column(velocity_name(n)) for n in self.position_names], axis=-1)
        else:
            velocities = np.stack([dataset.column(velocity_name(n)) for n in self.position_names], axis=-1)
        h = self.history
        n = dataset.n_samples
        parts = [positions[:, h:], velocities[:, h:]]
        parts += [positions[:, h - k : n - k] for k in range(1, h + 1)]
        return np.ascontiguousarray(np.concatenate(parts, axis=-1))

    def torques(self, dataset: TrajectoryDataset) -> np.ndarray:
        """Torques aligned with :meth:`states`: ``(T, N - history - 1)`` [N m], entry ``i`` acts from
        state ``i`` to state ``i + 1``."""
        return np.ascontiguousarray(dataset.torques_nm[:, self.history :])

    def transitions(self, dataset: TrajectoryDataset, trials: np.ndarray | None = None) -> "TransitionData":
        """All ``(state, torque, next state)`` triples of the given trials (default: all), flattened."""
        trials = np.arange(dataset.n_trials) if trials is None else np.asarray(trials, dtype=np.int64)
        states = self.states(dataset)[trials]
        torques = self.torques(dataset)[trials]
        return TransitionData(
            states=states[:, :-1].reshape(-1, self.dim),
            torques_nm=torques.reshape(-1),
            next_states=states[:, 1:].reshape(-1, self.dim),
        )


@dataclass(frozen=True, eq=False)
class TransitionData:
    """Flattened one-step transitions: ``states`` and ``next_states`` ``(M, d)``, ``torques_nm`` ``(M,)``."""

    states: np.ndarray
    torques_nm: np.ndarray
    next_states: np.ndarray

    def __len__(self) -> int:
        return int(self.states.shape[0])

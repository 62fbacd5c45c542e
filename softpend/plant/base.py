"""What every plant shares: argument checks, torque saturation, divergence reporting."""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from softpend.checks import int_at_least, positive
from softpend.plant.exudyn_adapter import ExudynSystem, SolverFailure
from softpend.plant.observation import Observation
from softpend.plant.params import RodParams

#: Most implicit-solver steps per control step.
MAX_SUBSTEPS = 1000


class SimulationDiverged(RuntimeError):
    """The simulation could not continue (solver failure or non-finite state); ``reason`` says why."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class PlantBase(ExudynSystem):
    """What every plant offers; ``q``: the coordinates, hub angle first (unwrapped) unless the hub is locked.  A
    subclass builds its Exudyn system, sets ``n_coordinates`` and supplies the methods that raise here."""

    params: RodParams
    dt_s: float
    substeps: int
    hub_locked: bool
    n_coordinates: int
    last_torque_nm: float

    def _init_common(
        self, params: Optional[RodParams], dt_s: float, substeps: int, hub_locked_at_rad: Optional[float]
    ) -> None:
        self.params = params if params is not None else RodParams()
        if not isinstance(self.params, RodParams):
            raise ValueError(f"params must be a RodParams, got {type(self.params).__name__}")
        self.dt_s = positive("dt_s", dt_s)
        self.substeps = int_at_least("substeps", substeps, 1)
        if self.substeps > MAX_SUBSTEPS:
            raise ValueError(f"substeps must be at most {MAX_SUBSTEPS} solver steps per control step, got {substeps!r}")
        if hub_locked_at_rad is not None and not math.isfinite(hub_locked_at_rad):
            raise ValueError(f"hub_locked_at_rad must be finite, got {hub_locked_at_rad!r}")
        self.hub_locked = hub_locked_at_rad is not None
        self._hub_angle_locked = float(hub_locked_at_rad or 0.0)
        self.last_torque_nm = 0.0

    def observe(self) -> Observation:
        """The observed variables now."""
        raise NotImplementedError

    def observation_from_state(self, q: np.ndarray, q_dot: np.ndarray) -> Observation:
        """The observation of a given state (the plant is not changed)."""
        raise NotImplementedError

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """``(q, q_dot)`` now (copies)."""
        raise NotImplementedError

    def link_points_m(self, q: Optional[np.ndarray] = None) -> np.ndarray:
        """Points along the rod, hub first [m]."""
        raise NotImplementedError

    def energy_j(self, q: Optional[np.ndarray] = None, qd: Optional[np.ndarray] = None) -> dict[str, float]:
        """Kinetic, gravitational, elastic and total energy [J]."""
        raise NotImplementedError

    def _set_state(self, q: np.ndarray, q_dot: np.ndarray) -> None:
        """Restart from ``(q, q_dot)`` at zero torque."""
        raise NotImplementedError

    def _set_torque(self, torque_nm: float) -> None:
        """The hub torque [N m] of the following steps."""
        raise NotImplementedError

    def _check_state(self, values: np.ndarray, name: str) -> np.ndarray:
        values = np.asarray(values, dtype=float)
        if values.shape != (self.n_coordinates,):
            raise ValueError(f"{name} must have shape ({self.n_coordinates},), got {values.shape}")
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{name} must be finite, got {values}")
        return values.copy()

    def reset(
        self, joint_angles_rad: Optional[np.ndarray] = None, joint_velocities_rad_s: Optional[np.ndarray] = None
    ) -> Observation:
        """Restart from ``(q, q_dot)`` (default: the straight rod upright at rest)."""
        given = {"joint_angles_rad": joint_angles_rad, "joint_velocities_rad_s": joint_velocities_rad_s}
        q, qd = (np.zeros(self.n_coordinates) if v is None else self._check_state(v, n) for n, v in given.items())
        self._set_state(q, qd)
        self.last_torque_nm = 0.0
        return self.observe()

    def hanging_state(self) -> tuple[np.ndarray, np.ndarray]:
        """State of the straight rod hanging down at rest (``phi = pi``)."""
        q = np.zeros(self.n_coordinates)
        if not self.hub_locked:
            q[0] = np.pi
        return q, np.zeros(self.n_coordinates)

    def step(self, torque_nm: float) -> Observation:
        """Hold a base torque (clipped to ``params.torque_limit_nm``) for one step ``dt_s``; raises ``ValueError`` for
        a non-finite torque, :class:`SimulationDiverged` if the solver fails."""
        torque = float(torque_nm)
        if not math.isfinite(torque):
            raise ValueError(f"torque_nm must be finite, got {torque_nm!r}")
        limit = self.params.torque_limit_nm
        self.last_torque_nm = torque = min(max(torque, -limit), limit)
        self._set_torque(torque)
        return self._solve(self.advance)

    def static_equilibrium(self) -> Observation:
        """Solve for static equilibrium at zero torque from the current state and make it the current state."""
        self.last_torque_nm = 0.0
        self._set_torque(0.0)
        return self._solve(self.solve_static)

    def _solve(self, solver) -> Observation:
        try:
            solver()
        except SolverFailure as exc:
            raise SimulationDiverged(str(exc)) from exc
        return self.observe()


#: The type of :func:`softpend.plant.make_plant`'s plants.
Plant = PlantBase

"""What every plant shares: argument checks, torque saturation, divergence reporting.

:class:`PlantBase` holds the plumbing common to the PRB chain (:class:`~softpend.plant.PRBPlant`) and the
continuum beam (:class:`~softpend.plant.beam.BeamPlant`); a plant supplies ``reset``,
``observation_from_state``/``observe``, ``joint_state`` and the solver hooks ``_advance(torque_nm)`` and
``_solve_static()``.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from softpend.checks import int_at_least, positive
from softpend.plant.exudyn_adapter import SolverFailure
from softpend.plant.observation import Observation
from softpend.plant.params import RodParams
from softpend.plant.protocol import Plant

__all__ = ["Plant", "PlantBase", "SimulationDiverged", "tilt_state"]


#: Most implicit-solver steps per control step: 1000.  The plants are stable at 2; a thousand times finer is
#: far past any accuracy gain, and a larger count would only make each step arbitrarily slow.
MAX_SUBSTEPS = 1000


class SimulationDiverged(RuntimeError):
    """The simulation could not continue (solver failure or non-finite state); ``reason`` says why."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


class PlantBase:
    """Shared part of the plants (see the module docstring).

    Attributes set by :meth:`_init_common`: ``params``, ``dt_s``, ``substeps``, ``hub_locked``,
    ``last_torque_nm``; the subclass sets ``n_coordinates``.
    """

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

    # ------------------------------------------------------------------ hooks of the subclasses
    def _set_state(self, q: np.ndarray, q_dot: np.ndarray) -> None:
        """Make the checked state ``(q, q_dot)`` the solver's current state with zero hub torque."""
        raise NotImplementedError

    def observe(self) -> Observation:
        raise NotImplementedError

    def _advance(self, torque_nm: float) -> None:
        """Hold ``torque_nm`` (already saturated) on the hub for one step ``dt_s``."""
        raise NotImplementedError

    def _solve_static(self) -> None:
        """Static equilibrium with zero torque from the current state, made the current state."""
        raise NotImplementedError

    # ------------------------------------------------------------------ shared behaviour
    def _check_state(self, values: np.ndarray, name: str) -> np.ndarray:
        values = np.asarray(values, dtype=float)
        if values.shape != (self.n_coordinates,):
            raise ValueError(f"{name} must have shape ({self.n_coordinates},), got {values.shape}")
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{name} must be finite, got {values}")
        return values.copy()

    def reset(
        self,
        joint_angles_rad: Optional[np.ndarray] = None,
        joint_velocities_rad_s: Optional[np.ndarray] = None,
    ) -> Observation:
        """Restart from a state (default: all zero, the straight rod pointing up at rest).

        Parameters
        ----------
        joint_angles_rad : array of shape (n_coordinates,)
            The plant's coordinates ``q``, hub angle first unless the hub is locked [rad; m for the beam's
            transverse coordinates].
        joint_velocities_rad_s : array of shape (n_coordinates,)
            Their rates ``q_dot`` [rad/s; m/s].

        Raises
        ------
        ValueError
            If a state has the wrong shape or is not finite.
        """
        q = (
            np.zeros(self.n_coordinates)
            if joint_angles_rad is None
            else self._check_state(joint_angles_rad, "joint_angles_rad")
        )
        qd = (
            np.zeros(self.n_coordinates)
            if joint_velocities_rad_s is None
            else self._check_state(joint_velocities_rad_s, "joint_velocities_rad_s")
        )
        self._set_state(q, qd)
        self.last_torque_nm = 0.0
        return self.observe()

    def set_joint_state(self, q: np.ndarray, q_dot: np.ndarray) -> Observation:
        """Alias of :meth:`reset`; used to branch from a stored state."""
        return self.reset(q, q_dot)

    def hanging_state(self) -> tuple[np.ndarray, np.ndarray]:
        """State of the straight rod hanging down at rest (``phi = pi``)."""
        q = np.zeros(self.n_coordinates)
        if not self.hub_locked:
            q[0] = np.pi
        return q, np.zeros(self.n_coordinates)

    def step(self, torque_nm: float) -> Observation:
        """Apply a base torque (clipped to ``params.torque_limit_nm``) for one step ``dt_s``.

        Raises
        ------
        ValueError
            If ``torque_nm`` is not finite.
        SimulationDiverged
            If the solver fails or the state stops being finite.
        """
        torque = float(torque_nm)
        if not math.isfinite(torque):
            raise ValueError(f"torque_nm must be finite, got {torque_nm!r}")
        limit = self.params.torque_limit_nm
        torque = min(max(torque, -limit), limit)
        self.last_torque_nm = torque
        try:
            self._advance(torque)
        except SolverFailure as exc:
            raise SimulationDiverged(str(exc)) from exc
        return self.observe()

    def static_equilibrium(self) -> Observation:
        """Solve for static equilibrium under gravity and elasticity (zero torque) with Exudyn's static
        solver, starting from the current state, and make it the current (resting) state.

        Most useful with ``hub_locked_at_rad`` set (a cantilever); with a free hub the result is whichever
        equilibrium the Newton iteration reaches from the current state.
        """
        self.last_torque_nm = 0.0
        try:
            self._solve_static()
        except SolverFailure as exc:
            raise SimulationDiverged(str(exc)) from exc
        return self.observe()


def tilt_state(params: RodParams, tilt_rad: float, plant: str = "prb") -> tuple[np.ndarray, np.ndarray]:
    """Straight rod at rest, hub and tip tilted by ``tilt_rad`` [rad] from upright, as ``(q, q_dot)`` of the
    plant named ``plant`` (any registered plant: its state is the hub angle followed by coordinates that are
    zero for the straight rod)."""
    from softpend.plant.registry import make_plant

    n = params.n_links + 1 if plant == "prb" else make_plant(plant, params=params).n_coordinates
    q = np.zeros(n)
    q[0] = tilt_rad
    return q, np.zeros_like(q)

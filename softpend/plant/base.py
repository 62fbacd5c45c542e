"""What every plant shares: argument checks, torque saturation, divergence reporting, and Exudyn's settings and
solver: one system stepped ``dt_s`` at a time by the implicit (generalized-alpha) solver."""

from __future__ import annotations

import contextlib
import functools
import math
from abc import ABC, abstractmethod
from typing import Any, Optional

import exudyn as exu
import numpy as np

from softpend.checks import int_at_least, positive
from softpend.plant.observation import Observation
from softpend.plant.params import RodParams

#: Most implicit-solver steps per control step.
MAX_SUBSTEPS = 1000


class SimulationDiverged(RuntimeError):
    """The simulation could not continue (solver failure or non-finite state); ``reason`` says why."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


#: What the Exudyn solver raises when Newton does not converge or the state becomes non-finite.
SolverFailure = SimulationDiverged


def _settings(values: dict[str, Any]) -> exu.SimulationSettings:
    """Quiet Exudyn settings with the dense linear solver and ``values`` set by dotted path."""
    settings = exu.SimulationSettings()
    quiet = {"solution.file.write": False, "show.computationTime": False, "show.statistics": False}
    for path, value in {**quiet, "linearSolver.solverType": exu.LinearSolverType.EXUdense, **values}.items():
        *parents, name = path.split(".")
        setattr(functools.reduce(getattr, parents, settings), name, value)
    return settings


def static_solver_settings(load_steps: int, relative_tolerance: float) -> exu.SimulationSettings:
    """Settings of Exudyn's static solver: ``load_steps`` load steps, quiet, dense."""
    s = "staticSolver."
    return _settings(
        {s + "numberOfLoadSteps": load_steps, s + "verboseMode": 0, s + "newton.relativeTolerance": relative_tolerance}
    )


class PlantBase(ABC):
    """What every plant offers; ``q``: the coordinates, hub angle first (unwrapped) unless the hub is locked.  A
    subclass builds its Exudyn system, sets ``n_coordinates`` and supplies the abstract methods: :meth:`observe`
    (the observation now), :meth:`observation_from_state` (of a given state, the plant unchanged),
    :meth:`joint_state` (``(q, q_dot)`` now, copies), :meth:`link_points_m` (points along the rod, hub first [m]),
    :meth:`energy_j` (kinetic, gravitational, elastic and total [J]), ``_set_state`` (restart from ``(q, q_dot)``
    at zero torque) and ``_set_torque`` (the hub torque [N m] of the following steps).  The Exudyn system is
    stepped ``dt_s`` at a time by ``substeps`` generalized-alpha steps (modified Newton, quiet, dense), a failed step
    retried with each of ``refinements`` times the steps."""

    params: RodParams
    dt_s: float
    substeps: int
    hub_locked: bool
    n_coordinates: int
    last_torque_nm: float
    time_s: float
    refinements: tuple[int, ...] = (1,)
    #: Whether a restart zeroes the accelerations and algebraic coordinates.
    zero_rest = False
    #: Load steps tried in turn and Newton tolerance of :meth:`static_equilibrium`.
    static_load_steps: tuple[int, ...] = (20,)
    static_tolerance = 1e-12

    def _start_solver(self, mbs: Any, spectral_radius: float, newton_relative_tolerance: float) -> None:
        self._mbs = mbs
        self.time_s = 0.0
        ti = "timeIntegration."
        self._settings = _settings(
            {
                ti + "numberOfSteps": int(self.substeps),
                ti + "startTime": 0.0,
                ti + "endTime": self.dt_s,
                ti + "verboseMode": 0,
                ti + "adaptiveStep": False,
                ti + "generalizedAlpha.spectralRadius": float(spectral_radius),
                ti + "newton.relativeTolerance": newton_relative_tolerance,
                ti + "newton.absoluteTolerance": 1e-10,
                ti + "newton.useModifiedNewton": True,
                ti + "newton.maxIterations": 50,
                "solution.sensors.writePeriod": 1e9,
            }
        )
        self._time_integration = self._settings.timeIntegration
        # Any: exudyn's stubs declare these methods without self and GetSystemState as lists (it gives arrays)
        self._data: Any = mbs.systemData
        self._solver: Any = exu.MainSolverImplicitSecondOrder()
        self._solver.InitializeSolver(mbs, self._settings)  # type: ignore[call-arg,misc]  # exudyn's stub lacks self

    def _set_coordinates(self, c: np.ndarray, c_t: np.ndarray) -> None:
        """Set the coordinates and their rates; restart the integrator from them."""
        data, zero_rest = self._data, self.zero_rest
        n_ae = len(data.GetAECoordinates()) if zero_rest else 0
        for configuration in (exu.ConfigurationType.Initial, exu.ConfigurationType.Current):
            data.SetODE2Coordinates(coordinates=c.tolist(), configuration=configuration)
            data.SetODE2Coordinates_t(coordinates=c_t.tolist(), configuration=configuration)
            if zero_rest:
                data.SetODE2Coordinates_tt(coordinates=[0.0] * len(c), configuration=configuration)
            if n_ae:
                data.SetAECoordinates(coordinates=[0.0] * n_ae, configuration=configuration)
        self.time_s = 0.0
        self._time_integration.startTime = 0.0
        self._time_integration.endTime = self.dt_s
        self._solver.InitializeSolver(self._mbs, self._settings)

    def advance(self) -> None:
        """Advance by one control step; ``SolverFailure`` if Newton fails at every refinement or the state is not
        finite."""
        settings, mbs, data, ti = self._settings, self._mbs, self._data, self._time_integration
        start_state = data.GetSystemState() if len(self.refinements) > 1 else None
        ok, reason = False, ""
        for refinement in self.refinements:
            if refinement > 1:  # again from the start of the step, with more solver steps
                for configuration in (exu.ConfigurationType.Initial, exu.ConfigurationType.Current):
                    data.SetSystemState(systemStateList=start_state, configuration=configuration)
                ti.numberOfSteps = int(self.substeps) * refinement
            ti.startTime = self.time_s
            ti.endTime = self.time_s + self.dt_s
            self._solver.InitializeSolverInitialConditions(mbs, settings)
            try:
                ok = bool(self._solver.SolveSteps(mbs, settings))
            except Exception as exc:  # Exudyn raises on e.g. singular Jacobians
                ok, reason = False, ": " + " ".join(str(exc).split())
            if ok:
                break
        if refinement > 1:
            ti.numberOfSteps = int(self.substeps)
        if not ok:
            raise SolverFailure(f"Exudyn implicit solver failed at t = {self.time_s:.4f} s{reason}")
        self._accept_step(data.GetSystemState())

    def _accept_step(self, state: Any, total: Optional[float] = None) -> None:
        """Make the solved ``state`` the start of the next step (``total``: the sum of its entries, if known)."""
        if not math.isfinite(float(np.sum(state[0])) + float(np.sum(state[1])) if total is None else total):
            raise SolverFailure(f"non-finite state at t = {self.time_s + self.dt_s:.4f} s")
        data, initial = self._data, exu.ConfigurationType.Initial
        data.SetSystemState(systemStateList=state, configuration=initial)
        data.SetODE2Coordinates_tt(coordinates=data.GetODE2Coordinates_tt(), configuration=initial)
        self.time_s += self.dt_s

    def _init_common(
        self, params: Optional[RodParams], dt_s: float, substeps: int, hub_locked_at_rad: Optional[float]
    ) -> Any:
        """Check and keep the common arguments; returns a new Exudyn system to build the plant in."""
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
        self._hub_offset = 0 if self.hub_locked else 1
        self._hub_angle_locked = float(hub_locked_at_rad or 0.0)
        self.last_torque_nm = 0.0
        self._sc = exu.SystemContainer()
        return self._sc.AddSystem()

    @abstractmethod
    def observe(self) -> Observation: ...
    @abstractmethod
    def observation_from_state(self, q: np.ndarray, q_dot: np.ndarray) -> Observation: ...
    @abstractmethod
    def joint_state(self) -> tuple[np.ndarray, np.ndarray]: ...
    @abstractmethod
    def link_points_m(self, q: Optional[np.ndarray] = None) -> np.ndarray: ...
    @abstractmethod
    def energy_j(self, q: Optional[np.ndarray] = None, qd: Optional[np.ndarray] = None) -> dict[str, float]: ...
    @abstractmethod
    def _set_state(self, q: np.ndarray, q_dot: np.ndarray) -> None: ...
    @abstractmethod
    def _set_torque(self, torque_nm: float) -> None: ...

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
        self.advance()
        return self.observe()

    def static_equilibrium(self) -> Observation:
        """Static equilibrium at zero torque from the current state (the first of ``static_load_steps`` that
        converges), made the resting and current state."""
        self.last_torque_nm = 0.0
        self._set_torque(0.0)
        start = np.array(self._data.GetODE2Coordinates())
        for steps in self.static_load_steps:
            settings = static_solver_settings(steps, self.static_tolerance)
            with contextlib.suppress(Exception):  # Exudyn raises on e.g. singular Jacobians
                if exu.SolveStatic(self._mbs, settings, updateInitialValues=True):
                    break
            self._set_coordinates(start, np.zeros(start.size))
        else:
            raise SolverFailure("Exudyn static solver did not converge")
        c = np.array(self._data.GetODE2Coordinates())
        self._set_coordinates(c, np.zeros(c.size))
        return self.observe()


#: The type of :func:`softpend.plant.make_plant`'s plants.
Plant = PlantBase

"""Exudyn's settings and solver shared by the plants: one system stepped ``dt_s`` at a time by the implicit
(generalized-alpha) solver."""

from __future__ import annotations

import functools
import math
from typing import Any, Optional

import exudyn as exu
import numpy as np


class SolverFailure(RuntimeError):
    """The Exudyn solver failed (Newton did not converge or the state became non-finite)."""


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


class ExudynSystem:
    """One Exudyn system stepped ``dt_s`` at a time by ``substeps`` generalized-alpha steps
    (modified Newton, quiet, dense), a failed step retried with each of ``refinements`` times the steps."""

    dt_s: float
    substeps: int
    time_s: float
    refinements: tuple[int, ...] = (1,)
    #: Whether a restart zeroes the accelerations and algebraic coordinates.
    zero_rest = False
    #: Load steps tried in turn and Newton tolerance of :meth:`solve_static`.
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

    def solve_static(self) -> None:
        """Static equilibrium under gravity, springs and the current loads (the first of ``static_load_steps`` that
        converges), made the resting state."""
        start = np.array(self._data.GetODE2Coordinates())
        ok = False
        for steps in self.static_load_steps:
            try:
                settings = static_solver_settings(steps, self.static_tolerance)
                ok = exu.SolveStatic(self._mbs, settings, updateInitialValues=True)
            except Exception:  # Exudyn raises on e.g. singular Jacobians
                ok = False
            if ok:
                break
            self._set_coordinates(start, np.zeros(start.size))
        if not ok:
            raise SolverFailure("Exudyn static solver did not converge")
        c = np.array(self._data.GetODE2Coordinates())
        self._set_coordinates(c, np.zeros(c.size))

"""A snake_case adapter over Exudyn for the continuum-beam rod: ``ObjectBeamGeometricallyExact2D`` elements on a
driven hub node (held at the origin; rotor inertia, viscous friction and torque on its rotation), in Exudyn's
global nodal coordinates."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional

import exudyn as exu
import numpy as np
from exudyn.itemInterface import (
    LoadCoordinate,
    LoadMassProportional,
    MarkerBodyMass,
    MarkerNodeCoordinate,
    NodePointGround,
    NodeRigidBody2D,
    ObjectBeamGeometricallyExact2D,
    ObjectConnectorCoordinate,
    ObjectConnectorCoordinateSpringDamper,
    ObjectMassPoint2D,
    ObjectRigidBody2D,
)

from softpend.plant.exudyn_adapter import SolverFailure, implicit_solver_settings, static_solver_settings


@dataclass(frozen=True)
class BeamSection:
    """Cross-section properties of a uniform beam per unit length (SI units; Kelvin-Voigt dampings)."""

    mass_per_length_kg_m: float
    rotary_inertia_kg_m: float
    bending_stiffness_nm2: float
    axial_stiffness_n: float
    shear_stiffness_n: float
    bending_damping_nm2s: float = 0.0
    axial_damping_ns: float = 0.0
    shear_damping_ns: float = 0.0


@dataclass
class HubBeam2D:
    """A planar beam (node 0 the hub) pointing up on a driven hub, stepped with the implicit solver;
    ``hub_locked_at_rad`` constrains the hub rotation (a cantilever)."""

    section: BeamSection
    length_m: float
    n_elements: int
    tip_mass_kg: float
    hub_inertia_kgm2: float
    hub_friction_nms_per_rad: float
    gravity_mps2: float
    dt_s: float
    substeps: int = 2
    hub_locked_at_rad: Optional[float] = None
    spectral_radius: float = 0.95
    newton_relative_tolerance: float = 1e-8
    time_s: float = field(init=False, default=0.0)

    def __post_init__(self) -> None:
        self.n_nodes = self.n_elements + 1
        self.n_ode2 = 3 * self.n_nodes
        self.element_length_m = self.length_m / self.n_elements
        self.node_s_m = np.linspace(0.0, self.length_m, self.n_nodes)
        sec = self.section
        self._sc = exu.SystemContainer()
        mbs = self._sc.AddSystem()
        self._mbs = mbs
        gravity = [0.0, -self.gravity_mps2, 0.0]
        ground = mbs.AddNode(NodePointGround(referenceCoordinates=[0.0, 0.0, 0.0]))
        self._nodes = [
            mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[0.0, float(s), 0.0], initialVelocities=[0.0, 0.0, 0.0]))
            for s in self.node_s_m
        ]
        for i in range(self.n_elements):
            element = mbs.AddObject(
                ObjectBeamGeometricallyExact2D(
                    nodeNumbers=[self._nodes[i], self._nodes[i + 1]],
                    length=self.element_length_m,
                    massPerLength=sec.mass_per_length_kg_m,
                    crossSectionInertia=sec.rotary_inertia_kg_m,
                    bendingStiffness=sec.bending_stiffness_nm2,
                    axialStiffness=sec.axial_stiffness_n,
                    shearStiffness=sec.shear_stiffness_n,
                    bendingDamping=sec.bending_damping_nm2s,
                    axialDamping=sec.axial_damping_ns,
                    shearDamping=sec.shear_damping_ns,
                )
            )
            if self.gravity_mps2 != 0:
                marker = mbs.AddMarker(MarkerBodyMass(bodyNumber=element))
                mbs.AddLoad(LoadMassProportional(markerNumber=marker, loadVector=gravity))
        if self.tip_mass_kg > 0:
            tip = mbs.AddObject(ObjectMassPoint2D(nodeNumber=self._nodes[-1], mass=self.tip_mass_kg))
            if self.gravity_mps2 != 0:
                marker = mbs.AddMarker(MarkerBodyMass(bodyNumber=tip))
                mbs.AddLoad(LoadMassProportional(markerNumber=marker, loadVector=gravity))
        ground_marker = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground, coordinate=0))
        hub = self._nodes[0]
        for coordinate in (0, 1):
            marker = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=hub, coordinate=coordinate))
            mbs.AddObject(ObjectConnectorCoordinate(markerNumbers=[ground_marker, marker]))
        hub_rotation = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=hub, coordinate=2))
        self._torque_load = None
        if self.hub_locked_at_rad is not None:
            mbs.AddObject(
                ObjectConnectorCoordinate(
                    markerNumbers=[ground_marker, hub_rotation], offset=float(self.hub_locked_at_rad)
                )
            )
        else:
            if self.hub_inertia_kgm2 > 0:
                mbs.AddObject(ObjectRigidBody2D(nodeNumber=hub, mass=0.0, inertia=self.hub_inertia_kgm2))
            if self.hub_friction_nms_per_rad > 0:
                mbs.AddObject(
                    ObjectConnectorCoordinateSpringDamper(
                        markerNumbers=[ground_marker, hub_rotation],
                        stiffness=0.0,
                        damping=self.hub_friction_nms_per_rad,
                    )
                )
            self._torque_load = mbs.AddLoad(LoadCoordinate(markerNumber=hub_rotation, load=0.0))
        mbs.Assemble()
        self._mass_matrix = self._compute_mass_matrix()

        settings = implicit_solver_settings(
            self.dt_s, self.substeps, self.spectral_radius, self.newton_relative_tolerance
        )
        self._settings = settings
        self._solver: Any = exu.MainSolverImplicitSecondOrder()  # Any: exudyn's stubs declare its methods without self
        self._solver.InitializeSolver(mbs, settings)  # type: ignore[call-arg,misc]  # exudyn's stub lacks self

    def set_coordinates(self, c: np.ndarray, c_t: np.ndarray) -> None:
        """Set the nodal coordinates ``(x, y, rotation)`` per node and their rates; restart the integrator."""
        c = np.asarray(c, dtype=float).reshape(self.n_ode2)
        c_t = np.asarray(c_t, dtype=float).reshape(self.n_ode2)
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(c_t))):
            raise ValueError("beam coordinates must be finite")
        data = self._mbs.systemData
        n_ae = len(data.GetAECoordinates())
        for configuration in (exu.ConfigurationType.Initial, exu.ConfigurationType.Current):
            data.SetODE2Coordinates(coordinates=c.tolist(), configuration=configuration)
            data.SetODE2Coordinates_t(coordinates=c_t.tolist(), configuration=configuration)
            data.SetODE2Coordinates_tt(coordinates=[0.0] * self.n_ode2, configuration=configuration)
            if n_ae:
                data.SetAECoordinates(coordinates=[0.0] * n_ae, configuration=configuration)
        self.time_s = 0.0
        self._settings.timeIntegration.startTime = 0.0
        self._settings.timeIntegration.endTime = self.dt_s
        self._solver.InitializeSolver(self._mbs, self._settings)

    def get_coordinates(self) -> tuple[np.ndarray, np.ndarray]:
        """Nodal coordinates and their rates (copies)."""
        data = self._mbs.systemData
        return np.array(data.GetODE2Coordinates()), np.array(data.GetODE2Coordinates_t())

    def set_hub_torque(self, torque_nm: float) -> None:
        """Hub torque [N m] for the following steps (ignored when the hub is locked)."""
        if self._torque_load is not None:
            self._mbs.SetLoadParameter(self._torque_load, "load", float(torque_nm))

    def _compute_mass_matrix(self) -> np.ndarray:
        solver: Any = exu.MainSolverStatic()  # Any: exudyn's stubs declare its methods without self
        solver.InitializeSolver(self._mbs, static_solver_settings(1, 1e-8))
        solver.ComputeMassMatrix(self._mbs)
        return np.array(solver.GetSystemMassMatrix(), dtype=float)[: self.n_ode2, : self.n_ode2]

    def mass_matrix(self) -> np.ndarray:
        """The (constant) mass matrix of the nodal coordinates."""
        return self._mass_matrix

    def advance(self) -> None:
        """Advance by one control step, retried with 4x and 16x the solver steps if Newton fails;
        ``SolverFailure`` if every try fails or the state is not finite."""
        settings = self._settings
        mbs = self._mbs
        data = mbs.systemData
        start_state = data.GetSystemState()
        ti = settings.timeIntegration
        ok = False
        for refinement in (1, 4, 16):
            if refinement > 1:
                for configuration in (exu.ConfigurationType.Initial, exu.ConfigurationType.Current):
                    data.SetSystemState(systemStateList=start_state, configuration=configuration)
            ti.numberOfSteps = int(self.substeps) * refinement
            ti.startTime = self.time_s
            ti.endTime = self.time_s + self.dt_s
            self._solver.InitializeSolverInitialConditions(mbs, settings)
            try:
                ok = bool(self._solver.SolveSteps(mbs, settings))
            except Exception:  # Exudyn raises on e.g. singular Jacobians
                ok = False
            if ok:
                break
        ti.numberOfSteps = int(self.substeps)
        if not ok:
            raise SolverFailure(f"Exudyn implicit solver failed at t = {self.time_s:.4f} s")
        state = data.GetSystemState()
        if not math.isfinite(float(np.sum(state[0])) + float(np.sum(state[1]))):
            raise SolverFailure(f"non-finite state at t = {self.time_s + self.dt_s:.4f} s")
        data.SetSystemState(systemStateList=state, configuration=exu.ConfigurationType.Initial)
        data.SetODE2Coordinates_tt(
            coordinates=data.GetODE2Coordinates_tt(), configuration=exu.ConfigurationType.Initial
        )
        self.time_s += self.dt_s

    def solve_static(self) -> np.ndarray:
        """Static equilibrium under the current hub torque (one load step, else 20), made the resting state."""
        start, _ = self.get_coordinates()
        for load_steps in (1, 20):
            try:
                ok = exu.SolveStatic(self._mbs, static_solver_settings(load_steps, 1e-8), updateInitialValues=True)
            except Exception:
                ok = False
            if ok:
                break
            self.set_coordinates(start, np.zeros(self.n_ode2))
        if not ok:
            raise SolverFailure("Exudyn static solver did not converge")
        c, _ = self.get_coordinates()
        self.set_coordinates(c, np.zeros(self.n_ode2))
        return c

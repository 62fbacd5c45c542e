"""Snake_case adapters over Exudyn: the PRB chain as a planar ``ObjectKinematicTree`` (one ``RevoluteZ`` joint per
link; springs and dampers as its P/D joint control) and the continuum rod as ``ObjectBeamGeometricallyExact2D``
elements on a driven hub node, both stepped by the implicit solver."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

import exudyn as exu
import numpy as np
from exudyn.itemInterface import (
    LoadCoordinate,
    LoadMassProportional,
    MarkerBodyMass,
    MarkerNodeCoordinate,
    NodeGenericODE2,
    NodePointGround,
    NodeRigidBody2D,
    ObjectBeamGeometricallyExact2D,
    ObjectConnectorCoordinate,
    ObjectConnectorCoordinateSpringDamper,
    ObjectKinematicTree,
    ObjectMassPoint2D,
    ObjectRigidBody2D,
)


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
    return _settings(
        {
            "staticSolver.numberOfLoadSteps": load_steps,
            "staticSolver.verboseMode": 0,
            "staticSolver.newton.relativeTolerance": relative_tolerance,
        }
    )


class _ExudynSystem:
    """What both models share: one Exudyn system stepped ``dt_s`` at a time by ``substeps`` generalized-alpha steps
    (modified Newton, quiet, dense), a failed step retried with each of ``refinements`` times the steps."""

    dt_s: float
    substeps: int
    spectral_radius: float
    newton_relative_tolerance: float
    refinements: tuple[int, ...] = (1,)

    def _start_solver(self, mbs: Any) -> None:
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
                ti + "generalizedAlpha.spectralRadius": float(self.spectral_radius),
                ti + "newton.relativeTolerance": self.newton_relative_tolerance,
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

    def _set_coordinates(self, c: np.ndarray, c_t: np.ndarray, zero_rest: bool = False) -> None:
        """Set the coordinates and their rates (and zero the accelerations and algebraic coordinates if
        ``zero_rest``); restart the integrator from them."""
        if not (np.all(np.isfinite(c)) and np.all(np.isfinite(c_t))):
            raise ValueError("the state must be finite")
        data = self._data
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

    def set_state(self, q: np.ndarray, q_t: np.ndarray) -> None:
        raise NotImplementedError

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

    def solve_static(self, load_steps: Sequence[int] = (20,), tolerance: float = 1e-12) -> np.ndarray:
        """Static equilibrium under gravity, springs and the current loads (the first of ``load_steps`` that
        converges), made the resting state; returns the coordinates."""
        start = np.array(self._data.GetODE2Coordinates())
        ok = False
        for steps in load_steps:
            try:
                ok = exu.SolveStatic(self._mbs, static_solver_settings(steps, tolerance), updateInitialValues=True)
            except Exception:  # Exudyn raises on e.g. singular Jacobians
                ok = False
            if ok:
                break
            self.set_state(start, np.zeros(start.size))
        if not ok:
            raise SolverFailure("Exudyn static solver did not converge")
        c = np.array(self._data.GetODE2Coordinates())
        self.set_state(c, np.zeros(c.size))
        return c


@dataclass(frozen=True)
class ChainLink:
    """One link of a planar chain: its joint's offset from the parent joint along the parent's axis, its mass,
    centre of mass from its joint, inertia about the centre of mass, and the joint's spring and damper."""

    joint_offset_m: float
    mass_kg: float
    com_m: float
    inertia_com_kgm2: float
    stiffness_nm_per_rad: float = 0.0
    damping_nms_per_rad: float = 0.0


@dataclass
class KinematicChain2D(_ExudynSystem):
    """A planar serial chain (links base first) pointing up (+y) at zero angles, gravity along -y, joint 0 at
    the origin rotated by ``base_angle_rad``."""

    links: Sequence[ChainLink]
    gravity_mps2: float
    dt_s: float
    substeps: int = 2
    base_angle_rad: float = 0.0
    spectral_radius: float = 0.95
    newton_relative_tolerance: float = 1e-8

    def __post_init__(self) -> None:
        n = self.n = len(self.links)
        if n < 1:
            raise ValueError("links must not be empty")
        self._force = np.zeros(n)
        self._sc = exu.SystemContainer()
        mbs = self._sc.AddSystem()
        node = mbs.AddNode(
            NodeGenericODE2(
                referenceCoordinates=[0.0] * n,
                initialCoordinates=[0.0] * n,
                initialCoordinates_t=[0.0] * n,
                numberOfODE2Coordinates=n,
            )
        )
        c, s = np.cos(self.base_angle_rad), np.sin(self.base_angle_rad)
        base_rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        # the ignores: exudyn's stub of these lists has no __init__
        transformations = exu.Matrix3DList([base_rotation] + [np.eye(3)] * (n - 1))  # type: ignore[call-arg]
        offsets = exu.Vector3DList([[0.0, link.joint_offset_m, 0.0] for link in self.links])  # type: ignore[call-arg]
        inertias = exu.Matrix3DList([np.eye(3) * link.inertia_com_kgm2 for link in self.links])  # type: ignore[call-arg]
        coms = exu.Vector3DList([[0.0, link.com_m, 0.0] for link in self.links])  # type: ignore[call-arg]
        self._tree = mbs.AddObject(
            ObjectKinematicTree(
                nodeNumber=node,
                jointTypes=[exu.JointType.RevoluteZ] * n,
                linkParents=list(range(-1, n - 1)),
                jointTransformations=transformations,
                jointOffsets=offsets,
                linkInertiasCOM=inertias,
                linkCOMs=coms,
                linkMasses=[link.mass_kg for link in self.links],
                gravity=[0.0, -self.gravity_mps2, 0.0],
                jointForceVector=[0.0] * n,
                jointPositionOffsetVector=[0.0] * n,
                jointVelocityOffsetVector=[0.0] * n,
                jointPControlVector=[link.stiffness_nm_per_rad for link in self.links],
                jointDControlVector=[link.damping_nms_per_rad for link in self.links],
            )
        )
        mbs.Assemble()
        self._start_solver(mbs)

    def set_state(self, q: np.ndarray, q_t: np.ndarray) -> None:
        """Set joint angles [rad] and joint rates [rad/s] and restart the integrator from them."""
        q = np.asarray(q, dtype=float).reshape(self.n)
        q_t = np.asarray(q_t, dtype=float).reshape(self.n)
        self._set_coordinates(q, q_t)
        self._q, self._q_t = q.copy(), q_t.copy()
        self._q_list, self._q_t_list = self._q.tolist(), self._q_t.tolist()

    def _accept_step(self, state: Any, total: Optional[float] = None) -> None:
        q_list, q_t_list = state[0].tolist(), state[1].tolist()
        super()._accept_step(state, sum(q_list) + sum(q_t_list))
        self._q, self._q_t, self._q_list, self._q_t_list = state[0], state[1], q_list, q_t_list

    def get_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint angles [rad] and rates [rad/s] (copies)."""
        return np.array(self._q, dtype=float), np.array(self._q_t, dtype=float)

    def get_state_lists(self) -> tuple[list[float], list[float]]:
        """Joint angles and rates as Python lists (valid until the next step)."""
        return self._q_list, self._q_t_list

    def set_joint_forces(self, forces: np.ndarray) -> None:
        """Generalised joint forces (torques) [N m] applied during the following steps."""
        self._force[:] = forces
        self._mbs.SetObjectParameter(self._tree, "jointForceVector", self._force)

    def linearized_system(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(M, K, D)`` of ``M dq_dd + D dq_d + K dq = forces`` linearised at the current state."""
        mass, stiffness, damping = self._mbs.ComputeLinearizedSystem()
        return np.asarray(mass), np.asarray(stiffness), np.asarray(damping)


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
class HubBeam2D(_ExudynSystem):
    """A planar beam (node 0 the hub, held at the origin; rotor inertia, viscous friction and torque on its
    rotation) pointing up, in Exudyn's global nodal coordinates; ``hub_locked_at_rad`` constrains the hub rotation
    (a cantilever)."""

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
    refinements: tuple[int, ...] = field(init=False, default=(1, 4, 16))

    def __post_init__(self) -> None:
        self.n_ode2 = 3 * (self.n_elements + 1)
        self.element_length_m = self.length_m / self.n_elements
        self.node_s_m = np.linspace(0.0, self.length_m, self.n_elements + 1)
        sec = self.section
        self._sc = exu.SystemContainer()
        mbs = self._sc.AddSystem()
        gravity = [0.0, -self.gravity_mps2, 0.0]
        ground = mbs.AddNode(NodePointGround(referenceCoordinates=[0.0, 0.0, 0.0]))
        nodes = [
            mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[0.0, float(s), 0.0], initialVelocities=[0.0, 0.0, 0.0]))
            for s in self.node_s_m
        ]
        bodies = [
            mbs.AddObject(
                ObjectBeamGeometricallyExact2D(
                    nodeNumbers=[nodes[i], nodes[i + 1]],
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
            for i in range(self.n_elements)
        ]
        if self.tip_mass_kg > 0:
            bodies.append(mbs.AddObject(ObjectMassPoint2D(nodeNumber=nodes[-1], mass=self.tip_mass_kg)))
        for body in bodies if self.gravity_mps2 != 0 else ():
            marker = mbs.AddMarker(MarkerBodyMass(bodyNumber=body))
            mbs.AddLoad(LoadMassProportional(markerNumber=marker, loadVector=gravity))
        ground_marker = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground, coordinate=0))
        hub = nodes[0]
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
        solver: Any = exu.MainSolverStatic()  # Any: exudyn's stubs declare its methods without self
        solver.InitializeSolver(mbs, static_solver_settings(1, 1e-8))
        solver.ComputeMassMatrix(mbs)
        #: The (constant) mass matrix of the nodal coordinates.
        self.mass_matrix = np.array(solver.GetSystemMassMatrix(), dtype=float)[: self.n_ode2, : self.n_ode2]
        self._start_solver(mbs)

    def set_state(self, c: np.ndarray, c_t: np.ndarray) -> None:
        """Set the nodal coordinates ``(x, y, rotation)`` per node and their rates; restart the integrator."""
        c = np.asarray(c, dtype=float).reshape(self.n_ode2)
        self._set_coordinates(c, np.asarray(c_t, dtype=float).reshape(self.n_ode2), zero_rest=True)

    def get_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Nodal coordinates and their rates (copies)."""
        return np.array(self._data.GetODE2Coordinates()), np.array(self._data.GetODE2Coordinates_t())

    def set_hub_torque(self, torque_nm: float) -> None:
        """Hub torque [N m] for the following steps (ignored when the hub is locked)."""
        if self._torque_load is not None:
            self._mbs.SetLoadParameter(self._torque_load, "load", float(torque_nm))

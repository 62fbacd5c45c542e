"""A snake_case adapter over Exudyn for the PRB chain: a planar ``ObjectKinematicTree`` (one ``RevoluteZ``
joint per link; springs and dampers as its P/D joint control) stepped by the implicit solver."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import exudyn as exu
import numpy as np
from exudyn.itemInterface import NodeGenericODE2, ObjectKinematicTree


class SolverFailure(RuntimeError):
    """The Exudyn solver failed (Newton did not converge or the state became non-finite)."""


def implicit_solver_settings(
    dt_s: float, substeps: int, spectral_radius: float, newton_relative_tolerance: float
) -> exu.SimulationSettings:
    """Generalized-alpha settings: ``substeps`` fixed steps per ``dt_s``, modified Newton, quiet, dense."""
    settings = exu.SimulationSettings()
    ti = settings.timeIntegration
    ti.numberOfSteps = int(substeps)
    ti.startTime = 0.0
    ti.endTime = dt_s
    ti.verboseMode = 0
    ti.adaptiveStep = False
    ti.generalizedAlpha.spectralRadius = float(spectral_radius)
    ti.newton.relativeTolerance = newton_relative_tolerance
    ti.newton.absoluteTolerance = 1e-10
    ti.newton.useModifiedNewton = True
    ti.newton.maxIterations = 50
    settings.solution.file.write = False
    settings.solution.sensors.writePeriod = 1e9
    settings.show.computationTime = False
    settings.show.statistics = False
    settings.linearSolver.solverType = exu.LinearSolverType.EXUdense
    return settings


def static_solver_settings(load_steps: int, relative_tolerance: float) -> exu.SimulationSettings:
    """Settings of Exudyn's static solver: ``load_steps`` load steps, quiet, dense."""
    settings = exu.SimulationSettings()
    settings.staticSolver.numberOfLoadSteps = load_steps
    settings.staticSolver.verboseMode = 0
    settings.staticSolver.newton.relativeTolerance = relative_tolerance
    settings.solution.file.write = False
    settings.show.computationTime = False
    settings.linearSolver.solverType = exu.LinearSolverType.EXUdense
    return settings


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
class KinematicChain2D:
    """A planar serial chain (links base first) pointing up (+y) at zero angles, gravity along -y, joint 0 at
    the origin rotated by ``base_angle_rad``; stepped by ``substeps`` implicit solver steps per ``dt_s``."""

    links: Sequence[ChainLink]
    gravity_mps2: float
    dt_s: float
    substeps: int = 2
    base_angle_rad: float = 0.0
    spectral_radius: float = 0.95
    newton_relative_tolerance: float = 1e-8
    _force: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        n = len(self.links)
        if n < 1:
            raise ValueError("links must not be empty")
        self.n = n
        self._force = np.zeros(n)
        self.time_s = 0.0
        self._sc = exu.SystemContainer()
        mbs = self._sc.AddSystem()
        self._mbs = mbs
        self._node = mbs.AddNode(
            NodeGenericODE2(
                referenceCoordinates=[0.0] * n,
                initialCoordinates=[0.0] * n,
                initialCoordinates_t=[0.0] * n,
                numberOfODE2Coordinates=n,
            )
        )
        c, s = np.cos(self.base_angle_rad), np.sin(self.base_angle_rad)
        base_rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        transformations = exu.Matrix3DList([base_rotation] + [np.eye(3)] * (n - 1))  # type: ignore[call-arg]  # exudyn's stub has no __init__
        offsets = exu.Vector3DList([[0.0, link.joint_offset_m, 0.0] for link in self.links])  # type: ignore[call-arg]  # exudyn's stub has no __init__
        inertias = exu.Matrix3DList(  # type: ignore[call-arg]  # exudyn's stub has no __init__
            [np.diag([link.inertia_com_kgm2, link.inertia_com_kgm2, link.inertia_com_kgm2]) for link in self.links]
        )
        coms = exu.Vector3DList([[0.0, link.com_m, 0.0] for link in self.links])  # type: ignore[call-arg]  # exudyn's stub has no __init__
        self._tree = mbs.AddObject(
            ObjectKinematicTree(
                nodeNumber=self._node,
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

        settings = implicit_solver_settings(
            self.dt_s, self.substeps, self.spectral_radius, self.newton_relative_tolerance
        )
        self._settings = settings
        self._time_integration = settings.timeIntegration
        # Any: exudyn's stubs declare these methods without self and GetSystemState as lists (it gives arrays)
        self._data: Any = mbs.systemData
        self._solver: Any = exu.MainSolverImplicitSecondOrder()
        self._solver.InitializeSolver(mbs, settings)  # type: ignore[call-arg,misc]  # exudyn's stub lacks self
        self._initial = exu.ConfigurationType.Initial

    def set_state(self, q: np.ndarray, q_t: np.ndarray) -> None:
        """Set joint angles [rad] and joint rates [rad/s] and restart the integrator from them."""
        q = np.asarray(q, dtype=float).reshape(self.n)
        q_t = np.asarray(q_t, dtype=float).reshape(self.n)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(q_t))):
            raise ValueError("joint state must be finite")
        data = self._mbs.systemData
        for configuration in (exu.ConfigurationType.Initial, exu.ConfigurationType.Current):
            data.SetODE2Coordinates(coordinates=q.tolist(), configuration=configuration)
            data.SetODE2Coordinates_t(coordinates=q_t.tolist(), configuration=configuration)
        self.time_s = 0.0
        self._q, self._q_t = q.copy(), q_t.copy()
        self._q_list, self._q_t_list = self._q.tolist(), self._q_t.tolist()
        self._settings.timeIntegration.startTime = 0.0
        self._settings.timeIntegration.endTime = self.dt_s
        self._solver.InitializeSolver(self._mbs, self._settings)

    def get_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint angles [rad] and rates [rad/s] (copies)."""
        return np.array(self._q, dtype=float), np.array(self._q_t, dtype=float)

    def get_state_views(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint angles and rates without copying (valid until the next step)."""
        return self._q, self._q_t

    def get_state_lists(self) -> tuple[list[float], list[float]]:
        """Joint angles and rates as Python lists (valid until the next step)."""
        return self._q_list, self._q_t_list

    def set_joint_forces(self, forces: np.ndarray) -> None:
        """Generalised joint forces (torques) [N m] applied during the following steps."""
        self._force[:] = forces
        self._mbs.SetObjectParameter(self._tree, "jointForceVector", self._force)

    def advance(self) -> None:
        """Advance by one control step; ``SolverFailure`` if Newton fails or the state is not finite."""
        settings = self._settings
        mbs = self._mbs
        solver = self._solver
        ti = self._time_integration
        ti.startTime = self.time_s
        ti.endTime = self.time_s + self.dt_s
        solver.InitializeSolverInitialConditions(mbs, settings)
        try:
            ok = solver.SolveSteps(mbs, settings)
        except exu.ExudynError as exc:
            raise SolverFailure(
                f"Exudyn implicit solver failed at t = {self.time_s:.4f} s: {' '.join(str(exc).split())}"
            ) from exc
        data = self._data
        state = data.GetSystemState()
        if not ok:
            raise SolverFailure(f"Exudyn implicit solver failed at t = {self.time_s:.4f} s")
        q, q_t = state[0], state[1]
        q_list, q_t_list = q.tolist(), q_t.tolist()
        if not math.isfinite(sum(q_list) + sum(q_t_list)):
            raise SolverFailure(f"non-finite state at t = {self.time_s + self.dt_s:.4f} s")
        self._q, self._q_t = q, q_t
        self._q_list, self._q_t_list = q_list, q_t_list
        initial = self._initial
        data.SetSystemState(systemStateList=state, configuration=initial)
        data.SetODE2Coordinates_tt(coordinates=data.GetODE2Coordinates_tt(), configuration=initial)
        self.time_s += self.dt_s

    def linearized_system(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(M, K, D)`` of ``M dq_dd + D dq_d + K dq = forces`` linearised at the current state."""
        mass, stiffness, damping = self._mbs.ComputeLinearizedSystem()
        return np.asarray(mass), np.asarray(stiffness), np.asarray(damping)

    def solve_static(self) -> np.ndarray:
        """Static equilibrium under gravity, springs and the current joint forces; returns joint angles."""
        try:
            ok = exu.SolveStatic(self._mbs, static_solver_settings(20, 1e-12), updateInitialValues=True)
        except exu.ExudynError as exc:
            raise SolverFailure(f"Exudyn static solver failed: {' '.join(str(exc).split())}") from exc
        if not ok:
            raise SolverFailure("Exudyn static solver did not converge")
        q = np.array(self._mbs.systemData.GetODE2Coordinates())
        self.set_state(q, np.zeros(self.n))
        return q

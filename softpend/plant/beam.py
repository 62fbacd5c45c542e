"""The continuum-beam soft pendulum: the PRB plant's hub driving a rod of Exudyn geometrically exact 2D beams.

State ``q = [phi, u_1, v_1, psi_1, ..., u_N, v_N, psi_N]``: the hub angle, then per node after the hub its
displacement in the hub frame from the straight rod (across, along) [m] and its rotation relative to the hub.
"""

from __future__ import annotations

import math
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

from softpend.checks import in_unit_interval, int_at_least, positive
from softpend.plant.base import PlantBase, static_solver_settings
from softpend.plant.observation import Observation, energies, observation_from_tip
from softpend.plant.params import RodParams

DEFAULT_N_ELEMENTS = 12
#: Poisson ratio of the rod material, for the shear stiffness only.
POISSON_RATIO = 0.45
#: Timoshenko shear correction factor of a rectangular cross-section.
SHEAR_CORRECTION = 5.0 / 6.0


def _section(params: RodParams) -> dict[str, float]:
    """Exudyn's section properties of the rod per unit length (SI units): the PRB chain's ``E*I``, bending damping
    ``zeta * L/n_links`` and its retardation time ``d_b/(E*I)`` for the axial and shear strains (Kelvin-Voigt)."""
    ei = params.bending_stiffness_nm2
    if ei <= 0:
        raise ValueError(
            "params.youngs_modulus_pa and params.stiffness_scale must be positive for the beam plant, got "
            f"E = {params.youngs_modulus_pa!r}, stiffness_scale = {params.stiffness_scale!r}"
        )
    area, scale, e = params.width_m * params.depth_m, params.stiffness_scale, params.youngs_modulus_pa
    ea, ga = e * area * scale, SHEAR_CORRECTION * (e / (2.0 * (1.0 + POISSON_RATIO))) * area * scale
    mu, damping = params.mass_kg / params.length_m, params.joint_damping_nms_per_rad * params.link_length_m
    values = (mu, mu * params.depth_m**2 / 12.0, ei, ea, ga, damping, damping / ei * ea, damping / ei * ga)
    names = (
        "massPerLength crossSectionInertia bendingStiffness axialStiffness shearStiffness bendingDamping axialDamping"
    )
    return dict(zip((*names.split(), "shearDamping"), values))


class BeamPlant(PlantBase):
    """Soft pendulum with the rod as a continuum beam; the interface of :class:`~softpend.plant.PRBPlant`
    (``n_links`` of ``params`` only sets the damping)."""

    refinements = (1, 4, 16)
    zero_rest = True
    static_load_steps = (1, 20)
    static_tolerance = 1e-8

    def __init__(
        self,
        params: Optional[RodParams] = None,
        dt_s: float = 0.01,
        substeps: int = 2,
        hub_locked_at_rad: Optional[float] = None,
        n_elements: int = DEFAULT_N_ELEMENTS,
        spectral_radius: float = 0.95,
        newton_relative_tolerance: float = 1e-6,
    ) -> None:
        mbs = self._init_common(params, dt_s, substeps, hub_locked_at_rad)
        self.n_elements = n = int_at_least("n_elements", n_elements, 1)
        in_unit_interval("spectral_radius", spectral_radius)
        positive("newton_relative_tolerance", newton_relative_tolerance)
        p = self.params
        sec = self.section = _section(p)
        self.n_coordinates = 3 * n + self._hub_offset
        self.element_length_m = p.length_m / n
        self._s = np.linspace(0.0, p.length_m, n + 1)
        ground = mbs.AddNode(NodePointGround(referenceCoordinates=[0.0, 0.0, 0.0]))
        nodes = [
            mbs.AddNode(NodeRigidBody2D(referenceCoordinates=[0.0, float(s), 0.0], initialVelocities=[0.0, 0.0, 0.0]))
            for s in self._s
        ]
        bodies = [
            mbs.AddObject(ObjectBeamGeometricallyExact2D(nodeNumbers=[a, b], length=self.element_length_m, **sec))
            for a, b in zip(nodes, nodes[1:])
        ]
        if p.tip_mass_kg > 0:
            bodies.append(mbs.AddObject(ObjectMassPoint2D(nodeNumber=nodes[-1], mass=p.tip_mass_kg)))
        for body in bodies if p.gravity_mps2 != 0 else ():
            marker = mbs.AddMarker(MarkerBodyMass(bodyNumber=body))
            mbs.AddLoad(LoadMassProportional(markerNumber=marker, loadVector=[0.0, -p.gravity_mps2, 0.0]))
        ground_marker = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground, coordinate=0))
        hub = nodes[0]
        for coordinate in (0, 1):
            marker = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=hub, coordinate=coordinate))
            mbs.AddObject(ObjectConnectorCoordinate(markerNumbers=[ground_marker, marker]))
        hub_rotation = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=hub, coordinate=2))
        self._torque_load = None
        ends = [ground_marker, hub_rotation]
        if hub_locked_at_rad is not None:
            mbs.AddObject(ObjectConnectorCoordinate(markerNumbers=ends, offset=self._hub_angle_locked))
        else:
            if p.hub_inertia_kgm2 > 0:
                mbs.AddObject(ObjectRigidBody2D(nodeNumber=hub, mass=0.0, inertia=p.hub_inertia_kgm2))
            if (friction := p.hub_friction_nms_per_rad) > 0:
                mbs.AddObject(
                    ObjectConnectorCoordinateSpringDamper(markerNumbers=ends, stiffness=0.0, damping=friction)
                )
            self._torque_load = mbs.AddLoad(LoadCoordinate(markerNumber=hub_rotation, load=0.0))
        mbs.Assemble()
        solver: Any = exu.MainSolverStatic()  # Any: exudyn's stubs declare its methods without self
        solver.InitializeSolver(mbs, static_solver_settings(1, 1e-8))
        solver.ComputeMassMatrix(mbs)
        #: The (constant) mass matrix of the nodal coordinates.
        self.mass_matrix = np.array(solver.GetSystemMassMatrix(), dtype=float)[: 3 * (n + 1), : 3 * (n + 1)]
        self._start_solver(mbs, spectral_radius, newton_relative_tolerance)
        self.reset()

    def _nodal_state(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array(self._data.GetODE2Coordinates()), np.array(self._data.GetODE2Coordinates_t())

    def global_coordinates(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exudyn's nodal coordinates ``(x, y, rotation)`` per node, hub first (displacements from the upright
        straight rod), and their rates, for a state."""
        phi, phi_dot = (self._hub_angle_locked, 0.0) if self.hub_locked else (float(q[0]), float(qd[0]))
        local = np.asarray(q[self._hub_offset :], float).reshape(self.n_elements, 3)
        local_dot = np.asarray(qd[self._hub_offset :], float).reshape(self.n_elements, 3)
        cs, sn = math.cos(phi), math.sin(phi)
        px, py, (u, v, w) = local[:, 0], self._s[1:] + local[:, 1], local_dot.T
        gx, gy = cs * px - sn * py, sn * px + cs * py
        c = np.column_stack([gx, gy - self._s[1:], phi + local[:, 2]])
        c_t = np.column_stack([cs * u - sn * v - phi_dot * gy, sn * u + cs * v + phi_dot * gx, phi_dot + w])
        return np.concatenate([[0.0, 0.0, phi], c.reshape(-1)]), np.concatenate([[0.0, 0.0, phi_dot], c_t.reshape(-1)])

    def _set_state(self, q: np.ndarray, q_dot: np.ndarray) -> None:
        self._set_coordinates(*self.global_coordinates(q, q_dot))
        self._set_torque(0.0)

    def _set_torque(self, torque_nm: float) -> None:
        if self._torque_load is not None:
            self._mbs.SetLoadParameter(self._torque_load, "load", float(torque_nm))

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """``(q, q_dot)`` (hub angle unwrapped): :meth:`global_coordinates` inverted."""
        c, c_t = (values.reshape(-1, 3) for values in self._nodal_state())
        phi, phi_dot = (self._hub_angle_locked, 0.0) if self.hub_locked else (float(c[0, 2]), float(c_t[0, 2]))
        cs, sn = math.cos(phi), math.sin(phi)
        gx, gy = c[1:, 0], c[1:, 1] + self._s[1:]
        vx, vy = c_t[1:, 0] + phi_dot * gy, c_t[1:, 1] - phi_dot * gx  # the rigid rotation removed
        local = np.column_stack([cs * gx + sn * gy, -sn * gx + cs * gy - self._s[1:], c[1:, 2] - phi])
        local_dot = np.column_stack([cs * vx + sn * vy, -sn * vx + cs * vy, c_t[1:, 2] - phi_dot])
        head, head_dot = ([], []) if self.hub_locked else ([phi], [phi_dot])
        return np.concatenate([head, local.reshape(-1)]), np.concatenate([head_dot, local_dot.reshape(-1)])

    def link_points_m(self, q: Optional[np.ndarray] = None) -> np.ndarray:
        """Positions ``(n_elements + 1, 2)`` of the beam nodes, hub axis first [m]."""
        q = None if q is None else self._check_state(q, "q")
        c = (self._nodal_state() if q is None else self.global_coordinates(q, np.zeros_like(q)))[0].reshape(-1, 3)
        return np.stack([c[:, 0], c[:, 1] + self._s], axis=1)

    def observe(self) -> Observation:
        return self._observation_from_global(*self._nodal_state())

    def observation_from_state(self, q: np.ndarray, qd: np.ndarray) -> Observation:
        """Observation of a given state (the plant is not changed)."""
        return self._observation_from_global(*self.global_coordinates(np.asarray(q, float), np.asarray(qd, float)))

    def _observation_from_global(self, c: np.ndarray, c_t: np.ndarray) -> Observation:
        ex, ey = float(c[-3]), float(c[-2]) + self.params.length_m
        return observation_from_tip(
            float(c[2]), float(c_t[2]), ex, ey, float(c_t[-3]), float(c_t[-2]), float(c[-1]), float(c_t[-1])
        )

    def energy_j(self, q: Optional[np.ndarray] = None, qd: Optional[np.ndarray] = None) -> dict[str, float]:
        """Kinetic (Exudyn's mass matrix), gravitational and elastic (Simo-Reissner strain energy at each
        element's midpoint) energy [J]."""
        if q is None or qd is None:
            c, c_t = self._nodal_state()
        else:
            c, c_t = self.global_coordinates(self._check_state(q, "q"), self._check_state(qd, "qd"))
        kinetic = 0.5 * float(c_t @ self.mass_matrix @ c_t)
        x, y, rot = c.reshape(-1, 3).T
        y = y + self._s
        sec, h, g = self.section, self.element_length_m, self.params.gravity_mps2
        gravity = g * sec["massPerLength"] * h * float(np.sum(0.5 * (y[:-1] + y[1:])))
        gravity += g * self.params.tip_mass_kg * float(y[-1])
        dx, dy = np.diff(x) / h, np.diff(y) / h
        mid = 0.5 * (rot[:-1] + rot[1:])
        tangent = -np.sin(mid) * dx + np.cos(mid) * dy
        normal = np.cos(mid) * dx + np.sin(mid) * dy
        curvature = np.diff(rot) / h
        strain = (
            sec["axialStiffness"] * (tangent - 1.0) ** 2
            + sec["shearStiffness"] * normal**2
            + sec["bendingStiffness"] * curvature**2
        )
        return energies(kinetic, gravity, 0.5 * h * float(np.sum(strain)))

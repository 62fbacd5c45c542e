"""The pseudo-rigid-body (PRB) soft pendulum on Exudyn: a motor hub carrying ``n`` rigid links joined by
torsional springs and dampers; coordinates are the hub angle from upright and the ``n`` spring angles."""

from __future__ import annotations

import math
from typing import Any, Optional

import exudyn as exu
import numpy as np
from exudyn.itemInterface import NodeGenericODE2, ObjectKinematicTree

from softpend.plant.base import PlantBase
from softpend.plant.observation import Observation, energies, observation_from_tip
from softpend.plant.params import RodParams


def link_inertials(params: RodParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masses [kg], centres of mass from the joint [m] and inertias about them [kg m^2] of the rod's links,
    the tip mass on the last."""
    n, length, m_l, m_t = params.n_links, params.link_length_m, params.link_mass_kg, params.tip_mass_kg
    masses, coms, inertias = np.full(n, m_l), np.full(n, length / 2), np.full(n, m_l * length**2 / 12)
    if m_t > 0:
        coms[-1] = c = (m_l * length / 2 + m_t * length) / (m_l + m_t)
        inertias[-1] = m_l * length**2 / 12 + m_l * (length / 2 - c) ** 2 + m_t * (length - c) ** 2
        masses[-1] = m_l + m_t
    return masses, coms, inertias


class PRBPlant(PlantBase):
    """Soft pendulum as a PRB chain on Exudyn's ``ObjectKinematicTree`` with the implicit solver.

    ``hub_locked_at_rad`` clamps the hub at that angle (a cantilever; no hub coordinate);
    ``spectral_radius`` is the generalized-alpha spectral radius (1: no numerical damping).
    """

    def __init__(
        self,
        params: Optional[RodParams] = None,
        dt_s: float = 0.01,
        substeps: int = 2,
        hub_locked_at_rad: Optional[float] = None,
        spectral_radius: float = 0.95,
    ) -> None:
        mbs = self._init_common(params, dt_s, substeps, hub_locked_at_rad)
        p = self.params
        self.link_masses_kg, self.link_coms_m, self.link_inertias_kgm2 = link_inertials(p)
        stiffness, damping = p.spring_stiffnesses_nm_per_rad(), p.spring_dampings_nms_per_rad()
        # per link: joint offset along the parent, mass, centre of mass, inertia about it, spring, damper
        links = [
            (0.0 if i == 0 else p.link_length_m, float(m), float(c), float(j), stiffness[i], damping[i])
            for i, (m, c, j) in enumerate(zip(self.link_masses_kg, self.link_coms_m, self.link_inertias_kgm2))
        ]
        if not self.hub_locked:  # the hub: a massless link of the rotor's inertia, damped by its friction
            links.insert(0, (0.0, 0.0, 0.0, p.hub_inertia_kgm2, 0.0, p.hub_friction_nms_per_rad))
        offsets, masses, coms, inertias, p_control, d_control = (list(column) for column in zip(*links))
        n = self.n_coordinates = len(links)
        self._forces = np.zeros(n)
        zeros = dict.fromkeys(("referenceCoordinates", "initialCoordinates", "initialCoordinates_t"), [0.0] * n)
        node = mbs.AddNode(NodeGenericODE2(**zeros, numberOfODE2Coordinates=n))
        c, s = np.cos(self._hub_angle_locked), np.sin(self._hub_angle_locked)
        base_rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        # the ignores: exudyn's stub of these lists has no __init__
        self._tree = mbs.AddObject(
            ObjectKinematicTree(
                nodeNumber=node,
                jointTypes=[exu.JointType.RevoluteZ] * n,
                linkParents=list(range(-1, n - 1)),
                jointTransformations=exu.Matrix3DList([base_rotation] + [np.eye(3)] * (n - 1)),  # type: ignore[call-arg]
                jointOffsets=exu.Vector3DList([[0.0, o, 0.0] for o in offsets]),  # type: ignore[call-arg]
                linkInertiasCOM=exu.Matrix3DList([np.eye(3) * i for i in inertias]),  # type: ignore[call-arg]
                linkCOMs=exu.Vector3DList([[0.0, c, 0.0] for c in coms]),  # type: ignore[call-arg]
                linkMasses=masses,
                gravity=[0.0, -p.gravity_mps2, 0.0],
                jointForceVector=[0.0] * n,
                jointPositionOffsetVector=[0.0] * n,
                jointVelocityOffsetVector=[0.0] * n,
                jointPControlVector=p_control,
                jointDControlVector=d_control,
            )
        )
        mbs.Assemble()
        self._start_solver(mbs, spectral_radius, 1e-8)
        self.reset()

    def _set_coordinates(self, q: np.ndarray, q_t: np.ndarray) -> None:
        super()._set_coordinates(q, q_t)
        self._q, self._q_t = q.copy(), q_t.copy()
        self._q_list, self._q_t_list = self._q.tolist(), self._q_t.tolist()

    def _accept_step(self, state: Any, total: Optional[float] = None) -> None:
        q_list, q_t_list = state[0].tolist(), state[1].tolist()
        super()._accept_step(state, sum(q_list) + sum(q_t_list))
        self._q, self._q_t, self._q_list, self._q_t_list = state[0], state[1], q_list, q_t_list

    def _set_state(self, q: np.ndarray, q_dot: np.ndarray) -> None:
        self._set_coordinates(q, q_dot)
        self.set_joint_forces(np.zeros(self.n_coordinates))

    def set_joint_forces(self, forces: np.ndarray) -> None:
        """Generalised joint forces (torques) [N m] applied during the following steps."""
        self._forces[:] = forces
        self._apply_forces()

    def _set_torque(self, torque_nm: float) -> None:
        if not self.hub_locked:
            self._forces[0] = torque_nm
            self._apply_forces()

    def _apply_forces(self) -> None:
        self._mbs.SetObjectParameter(self._tree, "jointForceVector", self._forces)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """``(q, q_dot)`` [rad, rad/s] (copies; hub angle unwrapped)."""
        return np.array(self._q, dtype=float), np.array(self._q_t, dtype=float)

    def linearized_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(M, K, D)`` of ``M dq_dd + D dq_d + K dq = e_0 tau`` linearised at the current state by Exudyn."""
        mass, stiffness, damping = self._mbs.ComputeLinearizedSystem()
        return np.asarray(mass), np.asarray(stiffness), np.asarray(damping)

    def _absolute_angles(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Absolute angle (from upright) and rate of each rod link."""
        if self.hub_locked:
            return self._hub_angle_locked + np.cumsum(q), np.cumsum(qd)
        return np.cumsum(q)[1:], np.cumsum(qd)[1:]

    def link_points_m(self, q: Optional[np.ndarray] = None) -> np.ndarray:
        """Positions ``(n + 1, 2)`` of the hub axis, every joint and the tip [m]."""
        if q is None:
            q, _ = self.joint_state()
        a, _ = self._absolute_angles(np.asarray(q, float), np.zeros_like(q, dtype=float))
        length = self.params.link_length_m
        steps = np.stack([-length * np.sin(a), length * np.cos(a)], axis=1)
        return np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])

    def observe(self) -> Observation:
        return self.observation_from_state(self._q_list, self._q_t_list)

    def observation_from_state(self, q, qd) -> Observation:
        """Observation of a joint state (scalar ``math``: faster than NumPy for a few links)."""
        length, locked, sin, cos = self.params.link_length_m, self.hub_locked, math.sin, math.cos
        angle = phi = self._hub_angle_locked if locked else float(q[0])
        rate = phi_dot = 0.0 if locked else float(qd[0])
        ex = ey = ex_dot = ey_dot = 0.0
        for i in range(0 if locked else 1, len(q)):
            angle += float(q[i])
            rate += float(qd[i])
            s_a, c_a = sin(angle), cos(angle)
            ex -= length * s_a
            ey += length * c_a
            ex_dot -= length * c_a * rate
            ey_dot -= length * s_a * rate
        return observation_from_tip(phi, phi_dot, ex, ey, ex_dot, ey_dot, angle, rate)

    def energy_j(self, q: Optional[np.ndarray] = None, qd: Optional[np.ndarray] = None) -> dict[str, float]:
        """Kinetic, gravitational and elastic energy [J], from the geometry."""
        if q is None or qd is None:
            q, qd = self.joint_state()
        a, ad = self._absolute_angles(q, qd)
        length, c, m, uy = self.params.link_length_m, self.link_coms_m, self.link_masses_kg, np.cos(a)
        steps = (length * uy, -length * np.cos(a) * ad, -length * np.sin(a) * ad)
        joint_y, joint_vx, joint_vy = (np.concatenate([[0.0], np.cumsum(x)[:-1]]) for x in steps)
        com_vx, com_vy = joint_vx - c * np.cos(a) * ad, joint_vy - c * np.sin(a) * ad
        kinetic = float(np.sum(0.5 * m * (com_vx**2 + com_vy**2) + 0.5 * self.link_inertias_kgm2 * ad**2))
        if not self.hub_locked:
            kinetic += 0.5 * self.params.hub_inertia_kgm2 * float(qd[0]) ** 2
        gravity = float(np.sum(m * self.params.gravity_mps2 * (joint_y + c * uy)))
        springs = np.asarray(self.params.spring_stiffnesses_nm_per_rad())
        elastic = float(0.5 * np.sum(springs * q[self._hub_offset :] ** 2))
        return energies(kinetic, gravity, elastic)

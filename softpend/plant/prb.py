"""The pseudo-rigid-body (PRB) soft pendulum on Exudyn: a motor hub carrying ``n`` rigid links joined by
torsional springs and dampers; coordinates are the hub angle from upright and the ``n`` spring angles."""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from softpend.plant.base import PlantBase, energies
from softpend.plant.exudyn_adapter import ChainLink, KinematicChain2D
from softpend.plant.observation import Observation, observation_from_tip
from softpend.plant.params import RodParams


def link_inertials(params: RodParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masses [kg], centres of mass from the joint [m] and inertias about them [kg m^2] of the rod's links,
    the tip mass on the last."""
    n = params.n_links
    length = params.link_length_m
    masses = np.full(n, params.link_mass_kg)
    coms = np.full(n, length / 2)
    inertias = np.full(n, params.link_mass_kg * length**2 / 12)
    if params.tip_mass_kg > 0:
        m_l, m_t = params.link_mass_kg, params.tip_mass_kg
        c = (m_l * length / 2 + m_t * length) / (m_l + m_t)
        inertias[-1] = m_l * length**2 / 12 + m_l * (length / 2 - c) ** 2 + m_t * (length - c) ** 2
        masses[-1] = m_l + m_t
        coms[-1] = c
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
        self._init_common(params, dt_s, substeps, hub_locked_at_rad)
        p = self.params
        length = p.link_length_m
        masses, coms, inertias = link_inertials(p)
        self.link_masses_kg = masses
        self.link_coms_m = coms
        self.link_inertias_kgm2 = inertias
        stiffness = p.spring_stiffnesses_nm_per_rad()
        damping = p.spring_dampings_nms_per_rad()
        links = [
            ChainLink(
                0.0 if i == 0 else length,
                float(masses[i]),
                float(coms[i]),
                float(inertias[i]),
                stiffness[i],
                damping[i],
            )
            for i in range(p.n_links)
        ]
        if not self.hub_locked:
            links.insert(0, ChainLink(0.0, 0.0, 0.0, p.hub_inertia_kgm2, 0.0, p.hub_friction_nms_per_rad))
        self._hub_offset = 0 if self.hub_locked else 1
        self._chain = KinematicChain2D(
            links=links,
            gravity_mps2=p.gravity_mps2,
            dt_s=self.dt_s,
            substeps=self.substeps,
            base_angle_rad=self._hub_angle_locked if self.hub_locked else 0.0,
            spectral_radius=spectral_radius,
        )
        self.n_coordinates = self._chain.n
        self._forces = np.zeros(self.n_coordinates)
        self.reset()

    @property
    def time_s(self) -> float:
        return self._chain.time_s

    def _set_state(self, q: np.ndarray, q_dot: np.ndarray) -> None:
        self._chain.set_state(q, q_dot)
        self._forces[:] = 0.0
        self._chain.set_joint_forces(self._forces)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """``(q, q_dot)`` [rad, rad/s] (copies; hub angle unwrapped)."""
        return self._chain.get_state()

    def _advance(self, torque_nm: float) -> None:
        if not self.hub_locked:
            self._forces[0] = torque_nm
            self._chain.set_joint_forces(self._forces)
        self._chain.advance()

    def _solve_static(self) -> None:
        if not self.hub_locked:
            self._forces[:] = 0.0
            self._chain.set_joint_forces(self._forces)
        self._chain.solve_static()

    def linearized_matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(M, K, D)`` of ``M dq_dd + D dq_d + K dq = e_0 tau`` linearised at the current state by Exudyn."""
        return self._chain.linearized_system()

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
        q, qd = self._chain.get_state_lists()
        return self.observation_from_state(q, qd)

    def observation_from_state(self, q, qd) -> Observation:
        """Observation of a joint state (scalar ``math``: faster than NumPy for a few links)."""
        length = self.params.link_length_m
        locked = self.hub_locked
        if locked:
            angle = phi = self._hub_angle_locked
            rate = phi_dot = 0.0
        else:
            angle = phi = float(q[0])
            rate = phi_dot = float(qd[0])
        ex = ey = ex_dot = ey_dot = 0.0
        sin, cos = math.sin, math.cos
        for i in range(0 if locked else 1, len(q)):
            if locked and i == 0:
                angle = self._hub_angle_locked + float(q[0])
                rate = float(qd[0])
            else:
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
        length = self.params.link_length_m
        uy = np.cos(a)
        joint_y = np.concatenate([[0.0], np.cumsum(length * uy)[:-1]])
        joint_vx = np.concatenate([[0.0], np.cumsum(-length * np.cos(a) * ad)[:-1]])
        joint_vy = np.concatenate([[0.0], np.cumsum(-length * np.sin(a) * ad)[:-1]])
        c = self.link_coms_m
        com_vx = joint_vx - c * np.cos(a) * ad
        com_vy = joint_vy - c * np.sin(a) * ad
        m = self.link_masses_kg
        kinetic = float(np.sum(0.5 * m * (com_vx**2 + com_vy**2) + 0.5 * self.link_inertias_kgm2 * ad**2))
        if not self.hub_locked:
            kinetic += 0.5 * self.params.hub_inertia_kgm2 * float(qd[0]) ** 2
        gravity = float(np.sum(m * self.params.gravity_mps2 * (joint_y + c * uy)))
        springs = np.asarray(self.params.spring_stiffnesses_nm_per_rad())
        elastic = float(0.5 * np.sum(springs * q[self._hub_offset :] ** 2))
        return energies(kinetic, gravity, elastic)

"""The pseudo-rigid-body (PRB) soft pendulum on Exudyn.

A motor hub (rotor inertia ``J``, viscous friction ``b``, base torque ``tau``) carries a rod of ``n`` equal
rigid links joined by torsional springs and dampers (see :mod:`softpend.plant.params` for the mapping
from ``E, W, D`` to the spring constants).  Generalised coordinates are the hub angle ``phi`` measured
from upright and the ``n`` spring angles (the first between hub and link 1), all counter-clockwise
positive, so the chain has ``n + 1`` degrees of freedom.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from softpend.plant.base import PlantBase, SimulationDiverged
from softpend.plant.exudyn_adapter import ChainLink, KinematicChain2D
from softpend.plant.observation import Observation, observation_from_tip
from softpend.plant.params import RodParams

__all__ = ["PRBPlant", "SimulationDiverged", "link_inertials"]


def link_inertials(params: RodParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Masses [kg], centres of mass from the link's joint [m] and inertias about the centre of mass [kg m^2]
    of the ``n`` rod links of ``params``, the tip mass riding on the last link."""
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

    Parameters
    ----------
    params : RodParams, optional
        Physical parameters (defaults: the project's default rod, see the book's introduction).
    dt_s : float
        Control step [s]; the torque is held constant (zero-order hold) over each step.
    substeps : int
        Implicit solver steps per control step (at least 2).
    hub_locked_at_rad : float, optional
        If given, the hub is clamped at this angle (no hub degree of freedom): a cantilever test rig.
    spectral_radius : float
        Generalized-alpha spectral radius (1 = energy-conserving trapezoidal rule for linear systems).

    Notes
    -----
    :meth:`step` clips the torque to ``params.torque_limit_nm`` (the motor saturates) and raises
    :class:`SimulationDiverged` instead of ever returning a non-finite state.
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
        n = p.n_links
        length = p.link_length_m
        masses, coms, inertias = link_inertials(p)
        self.link_masses_kg = masses
        self.link_coms_m = coms
        self.link_inertias_kgm2 = inertias
        stiffness = p.spring_stiffnesses_nm_per_rad()
        damping = p.spring_dampings_nms_per_rad()
        rod_links = [
            ChainLink(
                joint_offset_m=0.0 if i == 0 else length,
                mass_kg=float(masses[i]),
                com_m=float(coms[i]),
                inertia_com_kgm2=float(inertias[i]),
                stiffness_nm_per_rad=stiffness[i],
                damping_nms_per_rad=damping[i],
            )
            for i in range(n)
        ]
        if self.hub_locked:
            links = rod_links
            base_angle = self._hub_angle_locked
        else:
            hub = ChainLink(
                joint_offset_m=0.0,
                mass_kg=0.0,
                com_m=0.0,
                inertia_com_kgm2=p.hub_inertia_kgm2,
                stiffness_nm_per_rad=0.0,
                damping_nms_per_rad=p.hub_friction_nms_per_rad,
            )
            links = [hub] + rod_links
            base_angle = 0.0
        self._hub_offset = 0 if self.hub_locked else 1
        self._chain = KinematicChain2D(
            links=links,
            gravity_mps2=p.gravity_mps2,
            dt_s=self.dt_s,
            substeps=self.substeps,
            base_angle_rad=base_angle,
            spectral_radius=spectral_radius,
        )
        self.n_coordinates = self._chain.n
        self.last_torque_nm = 0.0
        self._forces = np.zeros(self.n_coordinates)
        self.reset()

    # ------------------------------------------------------------------ state
    @property
    def time_s(self) -> float:
        """Simulated time since the last reset [s]."""
        return self._chain.time_s

    def _set_state(self, q: np.ndarray, q_dot: np.ndarray) -> None:
        self._chain.set_state(q, q_dot)
        self._forces[:] = 0.0
        self._chain.set_joint_forces(self._forces)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Full joint state ``(q, q_dot)`` [rad, rad/s] (copies; hub angle unwrapped)."""
        return self._chain.get_state()

    # ------------------------------------------------------------------ stepping
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
        """``(M, K, D)`` of the joint-space dynamics linearised at the current state by Exudyn.

        ``M dq_dd + D dq_d + K dq = B tau`` with ``B = e_0`` (the torque acts on the hub coordinate).
        """
        return self._chain.linearized_system()

    # ------------------------------------------------------------------ kinematics
    def _absolute_angles(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Absolute angle (from upright) and rate of each rod link."""
        if self.hub_locked:
            a = self._hub_angle_locked + np.cumsum(q)
            ad = np.cumsum(qd)
        else:
            a = np.cumsum(q)[1:]
            ad = np.cumsum(qd)[1:]
        return a, ad

    def link_points_m(self, q: Optional[np.ndarray] = None) -> np.ndarray:
        """Positions ``(n + 1, 2)`` of the hub axis, every joint and the tip [m] (for drawing)."""
        if q is None:
            q, _ = self.joint_state()
        a, _ = self._absolute_angles(np.asarray(q, float), np.zeros_like(q, dtype=float))
        length = self.params.link_length_m
        steps = np.stack([-length * np.sin(a), length * np.cos(a)], axis=1)
        return np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])

    def observe(self) -> Observation:
        """The report's observed variables for the current state."""
        q, qd = self._chain.get_state_lists()
        return self.observation_from_state(q, qd)

    def observation_from_state(self, q, qd) -> Observation:
        """Observation for a given joint state (does not change the plant).

        Written with scalar ``math`` on purpose: for chains of a few links it is several times faster
        than NumPy, and it runs once per environment step.
        """
        length = self.params.link_length_m
        if self.hub_locked:
            angle, rate = self._hub_angle_locked, 0.0
            phi, phi_dot = self._hub_angle_locked, 0.0
            start = 0
        else:
            angle, rate = float(q[0]), float(qd[0])
            phi, phi_dot = angle, rate
            start = 1
        ex = ey = ex_dot = ey_dot = 0.0
        sin, cos = math.sin, math.cos
        for i in range(start, len(q)):
            if self.hub_locked and i == 0:
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

    # ------------------------------------------------------------------ energy
    def energy_j(self, q: Optional[np.ndarray] = None, qd: Optional[np.ndarray] = None) -> dict[str, float]:
        """Kinetic, gravitational and elastic energy [J], computed from the geometry (not by Exudyn)."""
        if q is None or qd is None:
            q, qd = self.joint_state()
        a, ad = self._absolute_angles(q, qd)
        length = self.params.link_length_m
        g = self.params.gravity_mps2
        # joint heights and velocities (start of each link)
        uy = np.cos(a)
        joint_y = np.concatenate([[0.0], np.cumsum(length * uy)[:-1]])
        vx_step = -length * np.cos(a) * ad
        vy_step = -length * np.sin(a) * ad
        joint_vx = np.concatenate([[0.0], np.cumsum(vx_step)[:-1]])
        joint_vy = np.concatenate([[0.0], np.cumsum(vy_step)[:-1]])
        c = self.link_coms_m
        com_y = joint_y + c * uy
        com_vx = joint_vx - c * np.cos(a) * ad
        com_vy = joint_vy - c * np.sin(a) * ad
        m = self.link_masses_kg
        kinetic = float(np.sum(0.5 * m * (com_vx**2 + com_vy**2) + 0.5 * self.link_inertias_kgm2 * ad**2))
        if not self.hub_locked:
            kinetic += 0.5 * self.params.hub_inertia_kgm2 * float(qd[0]) ** 2
        gravity = float(np.sum(m * g * com_y))
        springs = np.asarray(self.params.spring_stiffnesses_nm_per_rad())
        bend = q[self._hub_offset :]
        elastic = float(0.5 * np.sum(springs * bend**2))
        return {
            "kinetic_j": kinetic,
            "gravity_j": gravity,
            "elastic_j": elastic,
            "total_j": kinetic + gravity + elastic,
        }

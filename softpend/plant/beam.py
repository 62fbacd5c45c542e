"""The continuum-beam soft pendulum: the PRB plant's hub driving a rod of Exudyn geometrically exact 2D beams.

State ``q = [phi, u_1, v_1, psi_1, ..., u_N, v_N, psi_N]``: the hub angle, then per node after the hub its
displacement in the hub frame from the straight rod (across, along) [m] and its rotation relative to the hub.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from softpend.checks import in_unit_interval, int_at_least, positive
from softpend.plant.base import PlantBase, energies
from softpend.plant.exudyn_adapter import BeamSection, HubBeam2D
from softpend.plant.observation import Observation, observation_from_tip
from softpend.plant.params import RodParams

DEFAULT_N_ELEMENTS = 12
#: Poisson ratio of the rod material, for the shear stiffness only.
POISSON_RATIO = 0.45
#: Timoshenko shear correction factor of a rectangular cross-section.
SHEAR_CORRECTION = 5.0 / 6.0


def beam_section_from_params(params: RodParams) -> BeamSection:
    """Section of the rod of ``params``: the PRB chain's ``E*I``; bending damping ``zeta * L/n_links`` and the
    same retardation time ``d_b/(E*I)`` for the axial and shear strains."""
    ei = params.bending_stiffness_nm2
    if ei <= 0:
        raise ValueError(
            "params.youngs_modulus_pa and params.stiffness_scale must be positive for the beam plant, got "
            f"E = {params.youngs_modulus_pa!r}, stiffness_scale = {params.stiffness_scale!r}"
        )
    area = params.width_m * params.depth_m
    scale = params.stiffness_scale
    ea = params.youngs_modulus_pa * area * scale
    shear_modulus = params.youngs_modulus_pa / (2.0 * (1.0 + POISSON_RATIO))
    ga = SHEAR_CORRECTION * shear_modulus * area * scale
    mu = params.mass_kg / params.length_m
    bending_damping = params.joint_damping_nms_per_rad * params.link_length_m
    retardation_s = bending_damping / ei
    return BeamSection(
        mass_per_length_kg_m=mu,
        rotary_inertia_kg_m=mu * params.depth_m**2 / 12.0,
        bending_stiffness_nm2=ei,
        axial_stiffness_n=ea,
        shear_stiffness_n=ga,
        bending_damping_nm2s=bending_damping,
        axial_damping_ns=retardation_s * ea,
        shear_damping_ns=retardation_s * ga,
    )


class BeamPlant(PlantBase):
    """Soft pendulum with the rod as a continuum beam; the interface of :class:`~softpend.plant.PRBPlant`.

    ``n_links`` of ``params`` only sets the damping; ``newton_relative_tolerance`` is the solver's Newton
    tolerance.
    """

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
        self._init_common(params, dt_s, substeps, hub_locked_at_rad)
        self.n_elements = int_at_least("n_elements", n_elements, 1)
        in_unit_interval("spectral_radius", spectral_radius)
        p = self.params
        self.section = beam_section_from_params(p)
        self._beam = HubBeam2D(
            section=self.section,
            length_m=p.length_m,
            n_elements=self.n_elements,
            tip_mass_kg=p.tip_mass_kg,
            hub_inertia_kgm2=p.hub_inertia_kgm2,
            hub_friction_nms_per_rad=p.hub_friction_nms_per_rad,
            gravity_mps2=p.gravity_mps2,
            dt_s=self.dt_s,
            substeps=self.substeps,
            hub_locked_at_rad=hub_locked_at_rad,
            spectral_radius=spectral_radius,
            newton_relative_tolerance=positive("newton_relative_tolerance", newton_relative_tolerance),
        )
        self._s = self._beam.node_s_m
        self._hub_offset = 0 if self.hub_locked else 1
        self.n_coordinates = 3 * self.n_elements + self._hub_offset
        self.reset()

    @property
    def time_s(self) -> float:
        return self._beam.time_s

    def global_coordinates(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exudyn's nodal coordinates ``(x, y, rotation)`` per node, hub first (displacements from the upright
        straight rod), and their rates, for a state."""
        if self.hub_locked:
            phi, phi_dot = self._hub_angle_locked, 0.0
        else:
            phi, phi_dot = float(q[0]), float(qd[0])
        local = np.asarray(q[self._hub_offset :], float).reshape(self.n_elements, 3)
        local_dot = np.asarray(qd[self._hub_offset :], float).reshape(self.n_elements, 3)
        cs, sn = math.cos(phi), math.sin(phi)
        px = local[:, 0]
        py = self._s[1:] + local[:, 1]
        gx = cs * px - sn * py
        gy = sn * px + cs * py
        c = np.zeros((self.n_elements + 1, 3))
        c_t = np.zeros((self.n_elements + 1, 3))
        c[0, 2] = phi
        c_t[0, 2] = phi_dot
        c[1:, 0] = gx
        c[1:, 1] = gy - self._s[1:]
        c[1:, 2] = phi + local[:, 2]
        c_t[1:, 0] = cs * local_dot[:, 0] - sn * local_dot[:, 1] - phi_dot * gy
        c_t[1:, 1] = sn * local_dot[:, 0] + cs * local_dot[:, 1] + phi_dot * gx
        c_t[1:, 2] = phi_dot + local_dot[:, 2]
        return c.reshape(-1), c_t.reshape(-1)

    def state_from_global(self, c: np.ndarray, c_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`global_coordinates`."""
        c = np.asarray(c, float).reshape(-1, 3)
        c_t = np.asarray(c_t, float).reshape(-1, 3)
        phi = self._hub_angle_locked if self.hub_locked else float(c[0, 2])
        phi_dot = 0.0 if self.hub_locked else float(c_t[0, 2])
        cs, sn = math.cos(phi), math.sin(phi)
        gx = c[1:, 0]
        gy = c[1:, 1] + self._s[1:]
        vx = c_t[1:, 0] + phi_dot * gy  # the rigid rotation removed
        vy = c_t[1:, 1] - phi_dot * gx
        local = np.empty((self.n_elements, 3))
        local_dot = np.empty((self.n_elements, 3))
        local[:, 0] = cs * gx + sn * gy
        local[:, 1] = -sn * gx + cs * gy - self._s[1:]
        local[:, 2] = c[1:, 2] - phi
        local_dot[:, 0] = cs * vx + sn * vy
        local_dot[:, 1] = -sn * vx + cs * vy
        local_dot[:, 2] = c_t[1:, 2] - phi_dot
        head = [] if self.hub_locked else [phi]
        head_dot = [] if self.hub_locked else [phi_dot]
        return np.concatenate([head, local.reshape(-1)]), np.concatenate([head_dot, local_dot.reshape(-1)])

    def _set_state(self, q: np.ndarray, q_dot: np.ndarray) -> None:
        self._beam.set_state(*self.global_coordinates(q, q_dot))
        self._beam.set_hub_torque(0.0)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """``(q, q_dot)`` (hub angle unwrapped)."""
        return self.state_from_global(*self._beam.get_state())

    def _advance(self, torque_nm: float) -> None:
        self._beam.set_hub_torque(torque_nm)
        self._beam.advance()

    def _solve_static(self) -> None:
        self._beam.set_hub_torque(0.0)
        self._beam.solve_static((1, 20), 1e-8)

    def link_points_m(self, q: Optional[np.ndarray] = None) -> np.ndarray:
        """Positions ``(n_elements + 1, 2)`` of the beam nodes, hub axis first [m]."""
        if q is None:
            c, _ = self._beam.get_state()
        else:
            q = self._check_state(q, "q")
            c, _ = self.global_coordinates(q, np.zeros_like(q))
        c = c.reshape(-1, 3)
        return np.stack([c[:, 0], c[:, 1] + self._s], axis=1)

    def observe(self) -> Observation:
        return self._observation_from_global(*self._beam.get_state())

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
            c, c_t = self._beam.get_state()
        else:
            c, c_t = self.global_coordinates(self._check_state(q, "q"), self._check_state(qd, "qd"))
        kinetic = 0.5 * float(c_t @ self._beam.mass_matrix @ c_t)
        nodes = c.reshape(-1, 3)
        x = nodes[:, 0]
        y = nodes[:, 1] + self._s
        rot = nodes[:, 2]
        sec = self.section
        h = self._beam.element_length_m
        g = self.params.gravity_mps2
        gravity = g * sec.mass_per_length_kg_m * h * float(
            np.sum(0.5 * (y[:-1] + y[1:]))
        ) + g * self.params.tip_mass_kg * float(y[-1])
        dx = np.diff(x) / h
        dy = np.diff(y) / h
        mid = 0.5 * (rot[:-1] + rot[1:])
        tangent = -np.sin(mid) * dx + np.cos(mid) * dy
        normal = np.cos(mid) * dx + np.sin(mid) * dy
        curvature = np.diff(rot) / h
        strain = (
            sec.axial_stiffness_n * (tangent - 1.0) ** 2
            + sec.shear_stiffness_n * normal**2
            + sec.bending_stiffness_nm2 * curvature**2
        )
        return energies(kinetic, gravity, 0.5 * h * float(np.sum(strain)))

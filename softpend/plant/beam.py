"""The continuum-beam soft pendulum: the rod as geometrically exact beam elements on the motor hub.

The same hub as :class:`~softpend.plant.PRBPlant` (rotor inertia ``J``, viscous friction ``b``, base
torque ``tau``) drives a rod of ``n_elements`` Exudyn ``ObjectBeamGeometricallyExact2D`` elements (see
:mod:`softpend.plant.beam_adapter`), built from the same :class:`~softpend.plant.RodParams`.

Mapping from ``RodParams``
--------------------------
* mass per length ``rho*A = m/L``; rotary inertia per length ``rho*I = (m/L)*D**2/12``; tip mass on the
  last node;
* bending stiffness ``E*I = E*W*D**3/12 * stiffness_scale`` (the same ``E*I`` as the PRB springs), axial
  stiffness ``E*W*D * stiffness_scale``, shear stiffness ``kappa*G*W*D * stiffness_scale`` with
  ``kappa = 5/6`` (rectangle) and ``G = E/(2*(1 + nu))``, ``nu = POISSON_RATIO``;
* damping: the PRB chain lumps a rotational damper ``zeta`` over each link length ``h = L/n_links``
  (moment ``zeta * dq/dt`` with ``dq ~ kappa*h``), i.e. a Kelvin-Voigt bending damping
  ``d_b = zeta * L/n_links`` [N m^2 s] (moment ``d_b * dkappa/dt``).  The beam uses this ``d_b``, and the
  same retardation time ``tau_d = d_b/(E*I)`` for the axial and shear strains (stiffness-proportional,
  i.e. Rayleigh ``beta = tau_d``): mode ``i`` gets a damping ratio ``tau_d*omega_i/2``.  ``n_links`` is
  only used for this conversion; the beam's resolution is ``n_elements``.

State vector
------------
``q = [phi, u_1, v_1, psi_1, ..., u_N, v_N, psi_N]`` (``N = n_elements``): the unwrapped hub angle, then
for every beam node after the hub its displacement ``(u, v)`` [m] *in the hub frame* from the straight
rod (``u`` across, ``v`` along the rod) and its cross-section rotation ``psi`` relative to the hub [rad];
``q_dot`` holds their rates (hub-frame rates, so ``q_dot = [phi_dot, 0, ..., 0]`` is a rigid rotation).
With ``hub_locked_at_rad`` the hub angle is left out.  As for the PRB plant, ``q = 0`` is the straight
rod pointing up and ``hanging_state()`` sets ``q[0] = pi``.
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from softpend.checks import in_unit_interval, int_at_least, positive
from softpend.plant.base import PlantBase
from softpend.plant.beam_adapter import BeamSection, HubBeam2D
from softpend.plant.observation import Observation, observation_from_tip
from softpend.plant.params import RodParams

__all__ = ["BeamPlant", "DEFAULT_N_ELEMENTS", "POISSON_RATIO", "SHEAR_CORRECTION", "beam_section_from_params"]

#: Default number of beam elements: first two cantilever frequencies within 1.3 % of Euler-Bernoulli
#: (see the beam-reference chapter) at several thousand steps per second.
DEFAULT_N_ELEMENTS = 12
#: Poisson ratio of the rod material (a soft polymer), used for the shear stiffness only.
POISSON_RATIO = 0.45
#: Timoshenko shear correction factor of a rectangular cross-section.
SHEAR_CORRECTION = 5.0 / 6.0


def beam_section_from_params(params: RodParams) -> BeamSection:
    """Beam section properties from :class:`RodParams` (see the module docstring for the mapping).

    Raises
    ------
    ValueError
        If the bending stiffness is zero (a beam needs ``youngs_modulus_pa > 0`` and
        ``stiffness_scale > 0``).
    """
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
    """Soft pendulum with the rod as a continuum beam (Exudyn geometrically exact 2D beam elements).

    Offers the interface of :class:`~softpend.plant.PRBPlant` (same observations, torque input,
    ``SimulationDiverged`` on failure); registered as ``make_plant("beam", ...)``.

    Parameters
    ----------
    params : RodParams, optional
        Physical parameters (``n_links`` only sets the damping mapping, see the module docstring).
    dt_s : float
        Control step [s]; the torque is held constant over each step.
    substeps : int
        Implicit solver steps per control step.
    hub_locked_at_rad : float, optional
        If given, the hub is clamped at this angle (a cantilever test rig); the state then has no hub angle.
    n_elements : int
        Number of beam elements along the rod.
    spectral_radius : float
        Generalized-alpha spectral radius at infinity (1 = no numerical damping).
    newton_relative_tolerance : float
        Relative tolerance of the solver's Newton iteration (tighten it for validation runs with tiny
        amplitudes).
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
        self._s = self._beam.node_s_m  # reference arc length of the nodes [m]
        self._hub_offset = 0 if self.hub_locked else 1
        self.n_coordinates = 3 * self.n_elements + self._hub_offset
        self.reset()

    # ------------------------------------------------------------------ state mapping
    @property
    def time_s(self) -> float:
        """Simulated time since the last reset [s]."""
        return self._beam.time_s

    def _split(self, q: np.ndarray, qd: np.ndarray) -> tuple[float, float, np.ndarray, np.ndarray]:
        if self.hub_locked:
            phi, phi_dot = self._hub_angle_locked, 0.0
        else:
            phi, phi_dot = float(q[0]), float(qd[0])
        local = np.asarray(q[self._hub_offset :], float).reshape(self.n_elements, 3)
        local_dot = np.asarray(qd[self._hub_offset :], float).reshape(self.n_elements, 3)
        return phi, phi_dot, local, local_dot

    def global_coordinates(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exudyn's nodal coordinates ``(x, y, rotation)`` per node (hub first) and rates, for a state.

        Returns
        -------
        c, c_t : arrays of shape (3 * (n_elements + 1),)
            Displacements from the upright straight reference [m], absolute rotations [rad], and rates.
        """
        phi, phi_dot, local, local_dot = self._split(q, qd)
        cs, sn = math.cos(phi), math.sin(phi)
        # hub-frame positions of the nodes after the hub
        px = local[:, 0]
        py = self._s[1:] + local[:, 1]
        gx = cs * px - sn * py
        gy = sn * px + cs * py
        gvx = cs * local_dot[:, 0] - sn * local_dot[:, 1] - phi_dot * gy
        gvy = sn * local_dot[:, 0] + cs * local_dot[:, 1] + phi_dot * gx
        c = np.zeros((self.n_elements + 1, 3))
        c_t = np.zeros((self.n_elements + 1, 3))
        c[0, 2] = phi
        c_t[0, 2] = phi_dot
        c[1:, 0] = gx
        c[1:, 1] = gy - self._s[1:]
        c[1:, 2] = phi + local[:, 2]
        c_t[1:, 0] = gvx
        c_t[1:, 1] = gvy
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
        vx = c_t[1:, 0] + phi_dot * gy  # remove the rigid rotation: v - omega x r
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

    # ------------------------------------------------------------------ state
    def _set_state(self, q: np.ndarray, q_dot: np.ndarray) -> None:
        c, c_t = self.global_coordinates(q, q_dot)
        self._beam.set_coordinates(c, c_t)
        self._beam.set_hub_torque(0.0)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Full state ``(q, q_dot)`` (see the module docstring; hub angle unwrapped)."""
        return self.state_from_global(*self._beam.get_coordinates())

    # ------------------------------------------------------------------ stepping
    def _advance(self, torque_nm: float) -> None:
        self._beam.set_hub_torque(torque_nm)
        self._beam.advance()

    def _solve_static(self) -> None:
        self._beam.set_hub_torque(0.0)
        self._beam.solve_static()

    # ------------------------------------------------------------------ kinematics
    def node_positions_m(self, q: Optional[np.ndarray] = None) -> np.ndarray:
        """Positions ``(n_elements + 1, 2)`` of the beam nodes, hub axis first [m]."""
        if q is None:
            c, _ = self._beam.get_coordinates()
        else:
            q = self._check_state(q, "q")
            c, _ = self.global_coordinates(q, np.zeros_like(q))
        c = c.reshape(-1, 3)
        return np.stack([c[:, 0], c[:, 1] + self._s], axis=1)

    def link_points_m(self, q: Optional[np.ndarray] = None) -> np.ndarray:
        """Points along the rod for drawing: the node positions, hub axis first [m]."""
        return self.node_positions_m(q)

    def observe(self) -> Observation:
        """The report's observed variables for the current state."""
        c, c_t = self._beam.get_coordinates()
        return self._observation_from_global(c, c_t)

    def observation_from_state(self, q: np.ndarray, qd: np.ndarray) -> Observation:
        """Observation for a given state (does not change the plant)."""
        return self._observation_from_global(*self.global_coordinates(np.asarray(q, float), np.asarray(qd, float)))

    def _observation_from_global(self, c: np.ndarray, c_t: np.ndarray) -> Observation:
        phi, phi_dot = float(c[2]), float(c_t[2])
        ex = float(c[-3])
        ey = float(c[-2]) + self.params.length_m
        er, er_dot = float(c[-1]), float(c_t[-1])
        ex_dot, ey_dot = float(c_t[-3]), float(c_t[-2])
        return observation_from_tip(phi, phi_dot, ex, ey, ex_dot, ey_dot, er, er_dot)

    # ------------------------------------------------------------------ energy
    def energy_j(self, q: Optional[np.ndarray] = None, qd: Optional[np.ndarray] = None) -> dict[str, float]:
        """Kinetic, gravitational and elastic energy [J].

        Kinetic energy is ``c_t^T M c_t / 2`` with Exudyn's (constant) mass matrix; gravity uses the
        element mass centres and the tip mass; the elastic energy is the Simo-Reissner strain energy
        ``h/2 (EA eps^2 + GA gamma^2 + EI kappa^2)`` of each element evaluated at its midpoint (the
        elements' strains are constant for linear interpolation with one-point integration).
        """
        if q is None or qd is None:
            c, c_t = self._beam.get_coordinates()
        else:
            c, c_t = self.global_coordinates(self._check_state(q, "q"), self._check_state(qd, "qd"))
        mass = self._beam.mass_matrix()
        kinetic = 0.5 * float(c_t @ mass @ c_t)
        nodes = c.reshape(-1, 3)
        x = nodes[:, 0]
        y = nodes[:, 1] + self._s
        rot = nodes[:, 2]
        p = self.params
        sec = self.section
        h = self._beam.element_length_m
        g = p.gravity_mps2
        gravity = g * sec.mass_per_length_kg_m * h * float(np.sum(0.5 * (y[:-1] + y[1:]))) + g * p.tip_mass_kg * float(
            y[-1]
        )
        dx = np.diff(x) / h
        dy = np.diff(y) / h
        mid = 0.5 * (rot[:-1] + rot[1:])
        tangent = -np.sin(mid) * dx + np.cos(mid) * dy  # r' . t, with t = (-sin, cos) (upright at rotation 0)
        normal = np.cos(mid) * dx + np.sin(mid) * dy
        curvature = np.diff(rot) / h
        elastic = (
            0.5
            * h
            * float(
                np.sum(
                    sec.axial_stiffness_n * (tangent - 1.0) ** 2
                    + sec.shear_stiffness_n * normal**2
                    + sec.bending_stiffness_nm2 * curvature**2
                )
            )
        )
        return {
            "kinetic_j": kinetic,
            "gravity_j": gravity,
            "elastic_j": elastic,
            "total_j": kinetic + gravity + elastic,
        }

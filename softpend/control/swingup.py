"""Energy-based swing-up (pumping) that hands over to an LQR near upright.

The torque limit is about half the torque needed to hold the rod horizontal, so the motor cannot lift
the rod directly: it has to pump energy over several swings.  At the swing frequency (about 1 Hz, well
below the first bending mode) the rod moves as one body, so the motor's power into the swing is
``tau * theta_dot``; pushing with the tip rate while the rod's energy ``E`` is below the upright energy
``E_up`` raises ``E`` as fast as the torque limit allows::

    tau = sat(k_E * (E_up + E_margin - E) * theta_dot, tau_max)

(bang-bang for large ``k_E``, smooth near ``theta_dot = 0`` so the torque does not chatter).  The tip
rate, not the hub rate, sets the sign: the light hub on the compliant clamp vibrates against the rod, and
feedback on ``phi_dot`` pumps that vibration (a self-excited hub oscillation at the clamp mode) instead
of the swing.  Once the tip
is within ``capture_angle_rad`` of upright the LQR takes over; if the tip falls beyond
``release_angle_rad`` pumping resumes (hysteresis).

The rod is soft, so "its energy" needs a choice (``energy_source``):

* ``"observation"`` (any plant): the rod seen as a rigid pendulum through its tip:
  ``E = I_O theta_dot^2 / 2 + m g l (cos(theta) - 1)`` with ``I_O`` the inertia of hub, rod and tip mass
  about the hub axis and ``m g l = g (m L/2 + m_tip L)``; ``E_up = 0``.  Needs only ``theta`` and its rate.
* ``"joint"`` (default; PRB plant): the PRB chain's total mechanical energy (kinetic + gravity + elastic, from
  :meth:`softpend.plant.PRBPlant.energy_j` of a design copy of the plant) minus its value upright at rest.

:meth:`EnergySwingUpController.for_observations` builds the observation-only variant: tip energy with a larger
gain and an energy margin (the tip rate carries the bending vibration), and the LQR on observations.
"""

from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np

from softpend.checks import finite, one_of, positive
from softpend.control.lqr import LQRController, LQRWeights
from softpend.plant import Observation, PRBPlant, RodParams

__all__ = ["EnergySwingUpController", "pendulum_energy_j"]


def pendulum_energy_j(params: RodParams, theta_rad: float, theta_dot_rad_s: float) -> float:
    """Rigid-pendulum energy of the rod seen through its tip, zero upright at rest [J].

    ``E = I_O theta_dot^2 / 2 + g (m L/2 + m_tip L) (cos(theta) - 1)`` with
    ``I_O = J_hub + m L^2/3 + m_tip L^2``.
    """
    inertia = (
        params.hub_inertia_kgm2 + params.mass_kg * params.length_m**2 / 3 + params.tip_mass_kg * params.length_m**2
    )
    return 0.5 * inertia * theta_dot_rad_s**2 + params.gravity_torque_horizontal_nm * (math.cos(theta_rad) - 1.0)


class EnergySwingUpController:
    """Energy pumping from hanging plus LQR balance near upright (see the module docstring).

    Parameters
    ----------
    params : RodParams, optional
        Rod and hub used for the design (default rod).  For another plant (e.g. the continuum beam) pass
        its ``RodParams`` and use ``energy_source="observation"`` with an observation-feedback LQR.
    balance : Controller-like, optional
        The balancing controller; default ``LQRController.from_params(params, dt_s, state=lqr_state)``.
    dt_s : float
        Control step of the default LQR [s].
    lqr_state : {"joint", "observation"}
        Feedback path of the default LQR.
    energy_source : {"observation", "joint"}
        Energy used for pumping.
    energy_gain_per_j_rad_s : float
        ``k_E`` [N m / (J rad/s)]; large values give bang-bang pumping.
    energy_margin_j : float
        Target energy above upright [J], to make up for friction on the last swing.
    capture_angle_rad, release_angle_rad : float
        Hand over to the LQR inside ``capture_angle_rad``; resume pumping beyond ``release_angle_rad``.
    torque_limit_nm : float, optional
        Largest pumping torque [N m] (default ``params.torque_limit_nm``).
    """

    def __init__(
        self,
        params: Optional[RodParams] = None,
        balance: Optional[LQRController] = None,
        dt_s: float = 0.01,
        lqr_state: str = "joint",
        energy_source: str = "joint",
        energy_gain_per_j_rad_s: float = 5.0,
        energy_margin_j: float = 0.0,
        capture_angle_rad: float = 0.4,
        release_angle_rad: float = 0.8,
        torque_limit_nm: Optional[float] = None,
        lqr_weights: Optional[LQRWeights] = None,
    ) -> None:
        self.params = params if params is not None else RodParams()
        one_of("energy_source", energy_source, ("observation", "joint"))
        for name, value in (
            ("energy_gain_per_j_rad_s", energy_gain_per_j_rad_s),
            ("capture_angle_rad", capture_angle_rad),
            ("release_angle_rad", release_angle_rad),
        ):
            positive(name, value)
        if release_angle_rad < capture_angle_rad:
            raise ValueError(
                f"release_angle_rad ({release_angle_rad}) must not be smaller than capture_angle_rad ({capture_angle_rad})"
            )
        finite("energy_margin_j", energy_margin_j)
        self.torque_limit_nm = positive(
            "torque_limit_nm", self.params.torque_limit_nm if torque_limit_nm is None else torque_limit_nm
        )
        self.balance = (
            balance
            if balance is not None
            else LQRController.from_params(
                self.params, dt_s=dt_s, state=lqr_state, weights=lqr_weights, torque_limit_nm=self.torque_limit_nm
            )
        )
        self.energy_source = energy_source
        self.energy_gain = float(energy_gain_per_j_rad_s)
        self.energy_margin_j = float(energy_margin_j)
        self.capture_angle_rad = float(capture_angle_rad)
        self.release_angle_rad = float(release_angle_rad)
        self._design_plant: Optional[PRBPlant] = None
        self._upright_energy_j = 0.0
        if energy_source == "joint":
            self._design_plant = PRBPlant(self.params)
            n = self._design_plant.n_coordinates
            self._upright_energy_j = self._design_plant.energy_j(np.zeros(n), np.zeros(n))["total_j"]
        self.name = f"energy swing-up + {getattr(self.balance, 'name', 'LQR')}"
        self.reset()

    @classmethod
    def for_observations(
        cls, params: Optional[RodParams] = None, dt_s: float = 0.01, **kwargs
    ) -> "EnergySwingUpController":
        """Plant-agnostic variant: tip energy, LQR on observations, ``k_E = 50``, 0.02 J margin (any of
        which ``kwargs`` may override).  Uses only the report's observed variables, so it runs on any
        plant built from the same ``RodParams`` (e.g. the continuum beam)."""
        options: dict[str, Any] = dict(
            lqr_state="observation", energy_source="observation", energy_gain_per_j_rad_s=50.0, energy_margin_j=0.02
        )
        options.update(kwargs)
        return cls(params, dt_s=dt_s, **options)

    def reset(self) -> None:
        """Start in pumping mode."""
        self.balancing = False
        self.handover_time_s: Optional[float] = None
        if hasattr(self.balance, "reset"):
            self.balance.reset()

    def energy_j(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray) -> float:
        """Energy relative to upright at rest [J] from the chosen source."""
        if self._design_plant is not None:
            return (
                self._design_plant.energy_j(np.asarray(q, float), np.asarray(q_dot, float))["total_j"]
                - self._upright_energy_j
            )
        return pendulum_energy_j(self.params, observation.theta_rad, observation.theta_dot_rad_s)

    def pumping_torque_nm(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray) -> float:
        """The energy-pumping torque [N m] (saturated)."""
        error = self.energy_margin_j - self.energy_j(observation, q, q_dot)
        torque = self.energy_gain * error * observation.theta_dot_rad_s
        if observation.theta_dot_rad_s == 0.0 and error > 0:  # at rest: kick to start the first swing
            torque = self.torque_limit_nm
        return min(max(torque, -self.torque_limit_nm), self.torque_limit_nm)

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        angle = abs(observation.theta_rad)
        if self.balancing and angle > self.release_angle_rad:
            self.balancing = False
        elif not self.balancing and angle < self.capture_angle_rad:
            self.balancing = True
            if self.handover_time_s is None:
                self.handover_time_s = float(time_s)
            if hasattr(self.balance, "reset"):
                self.balance.reset()
        if self.balancing:
            return float(self.balance(observation, q, q_dot, time_s))
        return self.pumping_torque_nm(observation, q, q_dot)

"""Energy-based swing-up that hands over to an LQR near upright: pumping torque ``sat(k_E (E_up + E_margin - E)
theta_dot)`` on the tip rate (low-passed with ``rate_filter_s > 0``), ``E`` the rigid-pendulum energy seen through
the tip (``"observation"``) or the PRB chain's (``"joint"``); the LQR holds inside :data:`CAPTURE_ANGLE_RAD` until
:data:`RELEASE_ANGLE_RAD`."""

from __future__ import annotations

import math
from typing import Any, Callable, Optional

import numpy as np

from softpend.checks import non_negative, one_of
from softpend.control.lqr import LQRController
from softpend.plant import Observation, PRBPlant, RodParams

#: The LQR takes over inside this tip angle [rad] and hands back beyond the release angle.
CAPTURE_ANGLE_RAD, RELEASE_ANGLE_RAD = 0.4, 0.8


def pendulum_energy_j(params: RodParams, theta_rad: Any, theta_dot_rad_s: Any, cos: Callable = math.cos) -> Any:
    """Rigid-pendulum energy of the rod seen through its tip, zero upright at rest [J] (``cos``: e.g. ``torch.cos``)."""
    length = params.length_m
    inertia = params.hub_inertia_kgm2 + params.mass_kg * length**2 / 3 + params.tip_mass_kg * length**2
    return 0.5 * inertia * theta_dot_rad_s**2 + params.gravity_torque_horizontal_nm * (cos(theta_rad) - 1.0)


class EnergySwingUpController:
    """Energy pumping from hanging plus ``LQRController.from_params(params, dt_s, state=lqr_state)`` balancing near
    upright (see the module docstring)."""

    def __init__(
        self,
        params: Optional[RodParams] = None,
        dt_s: float = 0.01,
        lqr_state: str = "joint",
        energy_source: str = "joint",
        energy_gain_per_j_rad_s: float = 5.0,
        energy_margin_j: float = 0.0,
        rate_filter_s: float = 0.0,
    ) -> None:
        self.params = params if params is not None else RodParams()
        self.energy_source = one_of("energy_source", energy_source, ("observation", "joint"))
        self.energy_gain, self.energy_margin_j = float(energy_gain_per_j_rad_s), float(energy_margin_j)
        self._rate_gain = float(dt_s) / (non_negative("rate_filter_s", rate_filter_s) + float(dt_s))
        self.torque_limit_nm = self.params.torque_limit_nm
        self.balance = LQRController.from_params(self.params, dt_s=dt_s, state=lqr_state)
        self._design_plant: Optional[PRBPlant] = None
        self._upright_energy_j = 0.0
        if energy_source == "joint":
            self._design_plant = PRBPlant(self.params)
            n = self._design_plant.n_coordinates
            self._upright_energy_j = self._design_plant.energy_j(np.zeros(n), np.zeros(n))["total_j"]
        self.name = f"energy swing-up + {self.balance.name}"
        self.reset()

    @classmethod
    def for_observations(
        cls, params: Optional[RodParams] = None, dt_s: float = 0.01, **kwargs
    ) -> "EnergySwingUpController":
        """The variant for any plant: tip energy, LQR on observations, ``k_E = 50``, 0.02 J margin, 50 ms filter."""
        options: dict[str, Any] = dict(lqr_state="observation", energy_source="observation", rate_filter_s=0.05)
        options.update(energy_gain_per_j_rad_s=50.0, energy_margin_j=0.02)
        return cls(params, dt_s=dt_s, **{**options, **kwargs})

    def reset(self) -> None:
        """Start in pumping mode."""
        self.balancing = False
        self.handover_time_s: Optional[float] = None
        self._rate_rad_s: Optional[float] = None
        self.balance.reset()

    def energy_j(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray) -> float:
        """Energy relative to upright at rest [J]."""
        if self._design_plant is not None:
            energy = self._design_plant.energy_j(np.asarray(q, float), np.asarray(q_dot, float))["total_j"]
            return energy - self._upright_energy_j
        return pendulum_energy_j(self.params, observation.theta_rad, self._tip_rate(observation))

    def _tip_rate(self, observation: Observation) -> float:
        return observation.theta_dot_rad_s if self._rate_rad_s is None else self._rate_rad_s

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        if self._rate_gain < 1.0:
            rate = observation.theta_dot_rad_s
            last = rate if self._rate_rad_s is None else self._rate_rad_s
            self._rate_rad_s = last + self._rate_gain * (rate - last)
        angle = abs(observation.theta_rad)
        if self.balancing and angle > RELEASE_ANGLE_RAD:
            self.balancing = False
        elif not self.balancing and angle < CAPTURE_ANGLE_RAD:
            self.balancing = True
            if self.handover_time_s is None:
                self.handover_time_s = float(time_s)
            self.balance.reset()
        if self.balancing:
            return float(self.balance(observation, q, q_dot, time_s))
        error, rate = self.energy_margin_j - self.energy_j(observation, q, q_dot), self._tip_rate(observation)
        # pumping; at rest below the target energy a kick starts the first swing
        torque = self.torque_limit_nm if rate == 0.0 and error > 0 else self.energy_gain * error * rate
        return min(max(torque, -self.torque_limit_nm), self.torque_limit_nm)

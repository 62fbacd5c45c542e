"""A PILCO policy (or random torques) as a :class:`softpend.evaluation.Controller` with a zero-order hold."""

from __future__ import annotations

import math

import numpy as np

from softpend.checks import positive
from softpend.pilco.policy import LinearPolicy, RBFPolicy
from softpend.pilco.propagation import StateSpec
from softpend.plant import Observation, wrap_angle_rad


class _HoldController:
    def __init__(self, control_dt_s: float) -> None:
        self.control_dt_s = positive("control_dt_s", control_dt_s)
        self.reset()

    def reset(self) -> None:
        self._next_update_s, self._torque_nm, self._n_updates = 0.0, 0.0, 0

    def _compute(self, observation: Observation) -> float:
        raise NotImplementedError

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        if time_s >= self._next_update_s - 1e-9:
            self._torque_nm = float(self._compute(observation))
            self._n_updates += 1
            self._next_update_s = self._n_updates * self.control_dt_s
        return self._torque_nm


def in_balance_band(spec: StateSpec, states: np.ndarray, within_rad: float, within_rad_s: float) -> np.ndarray:
    """Which states (rows) have the tip within ``within_rad`` of upright [rad] and its rate within ``within_rad_s``
    of zero [rad/s]."""
    states = np.atleast_2d(states)
    tip = wrap_angle_rad(states[:, spec.tip_angle_index])
    return (np.abs(tip) < within_rad) & (np.abs(states[:, spec.tip_rate_index]) < within_rad_s)


class PilcoController(_HoldController):
    """Run an :class:`RBFPolicy` on the observed variables of :class:`StateSpec` ``spec``."""

    def __init__(
        self,
        policy: RBFPolicy,
        spec: StateSpec,
        control_dt_s: float,
        balance_policy: LinearPolicy | None = None,
        balance_band: tuple[float, float] | None = None,
    ) -> None:
        for name, p in (("policy", policy), ("balance_policy", balance_policy)):
            if p is not None and p.n_inputs != spec.n_model_inputs:
                raise ValueError(
                    f"{name} takes {p.n_inputs} inputs but state {spec.name!r} gives {spec.n_model_inputs}"
                )
        if balance_policy is not None:
            if balance_band is None or len(balance_band) != 2:
                raise ValueError(
                    f"balance_band must be (within_rad, within_rad_s) with a balance_policy, got {balance_band!r}"
                )
            balance_band = (positive("balance_band[0]", balance_band[0]), positive("balance_band[1]", balance_band[1]))
        self.policy, self.balance_policy, self.balance_band, self.spec = policy, balance_policy, balance_band, spec
        super().__init__(control_dt_s)

    def _compute(self, observation: Observation) -> float:
        state = self.spec.from_observations(observation.as_array()[None, :])
        policy: RBFPolicy | LinearPolicy = self.policy
        band = self.balance_band
        if self.balance_policy is not None and band is not None and in_balance_band(self.spec, state, *band)[0]:
            policy = self.balance_policy
        return float(policy.torque_nm(self.spec.model_inputs(state))[0])


class RandomTorqueController(_HoldController):
    """Random torques in ``[-torque_limit_nm, torque_limit_nm]``, each held for a random whole number of control periods."""

    def __init__(
        self,
        torque_limit_nm: float,
        control_dt_s: float,
        seed: int,
        hold_s: tuple[float, float] | None = None,
        bang_bang: bool = False,
    ) -> None:
        self.torque_limit_nm = positive("torque_limit_nm", torque_limit_nm)
        positive("control_dt_s", control_dt_s)
        hold = (control_dt_s, control_dt_s) if hold_s is None else tuple(float(h) for h in hold_s)
        if len(hold) != 2 or not all(math.isfinite(h) and h > 0 for h in hold) or hold[0] > hold[1]:
            raise ValueError(f"hold_s must be (min, max) with 0 < min <= max, got {hold_s!r}")
        self.seed, self.bang_bang = int(seed), bool(bang_bang)
        self.hold_periods = (max(1, int(round(hold[0] / control_dt_s))), max(1, int(round(hold[1] / control_dt_s))))
        super().__init__(control_dt_s)

    def reset(self) -> None:
        super().reset()
        self._rng, self._periods_left, self._held_nm = np.random.default_rng(self.seed), 0, 0.0

    def _compute(self, observation: Observation) -> float:
        if self._periods_left <= 0:
            if self.bang_bang:
                self._held_nm = self.torque_limit_nm * float(self._rng.choice((-1.0, 1.0)))
            else:
                self._held_nm = float(self._rng.uniform(-self.torque_limit_nm, self.torque_limit_nm))
            low, high = self.hold_periods
            self._periods_left = low if low == high else int(self._rng.integers(low, high + 1))
        self._periods_left -= 1
        return self._held_nm

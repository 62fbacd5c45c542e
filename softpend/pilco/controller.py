"""A PILCO policy (or random torques) as a :class:`softpend.evaluation.Controller` with a zero-order hold."""

from __future__ import annotations

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
    """Run an :class:`RBFPolicy` on the observed variables of :class:`StateSpec` ``spec``; the balancing policy,
    if any, within ``balance_band`` (within_rad, within_rad_s) of upright."""

    def __init__(
        self,
        policy: RBFPolicy,
        spec: StateSpec,
        control_dt_s: float,
        balance_policy: LinearPolicy | None = None,
        balance_band: tuple[float, float] | None = None,
    ) -> None:
        n_inputs = policy.centers.shape[1]
        if n_inputs != spec.n_model_inputs:
            raise ValueError(f"policy takes {n_inputs} inputs but state {spec.name!r} gives {spec.n_model_inputs}")
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
    """Bang-bang torques ``+-torque_limit_nm``, each held for a random whole number of control periods within
    ``hold_s`` (min, max) [s]."""

    def __init__(self, torque_limit_nm: float, control_dt_s: float, seed: int, hold_s: tuple[float, float]) -> None:
        self.torque_limit_nm, self.seed = positive("torque_limit_nm", torque_limit_nm), int(seed)
        dt = positive("control_dt_s", control_dt_s)
        if len(hold_s) != 2 or not 0 < hold_s[0] <= hold_s[1]:
            raise ValueError(f"hold_s must be (min, max) with 0 < min <= max, got {hold_s!r}")
        self.hold_periods = (max(1, int(round(hold_s[0] / dt))), max(1, int(round(hold_s[1] / dt))))
        super().__init__(control_dt_s)

    def reset(self) -> None:
        super().reset()
        self._rng, self._periods_left, self._held_nm = np.random.default_rng(self.seed), 0, 0.0

    def _compute(self, observation: Observation) -> float:
        if self._periods_left <= 0:
            self._held_nm = self.torque_limit_nm * float(self._rng.choice((-1.0, 1.0)))
            low, high = self.hold_periods
            self._periods_left = low if low == high else int(self._rng.integers(low, high + 1))
        self._periods_left -= 1
        return self._held_nm

"""Linear-quadratic regulators about upright (python-control), applied with saturation.

Feedback on the joint state ``[q, q_dot]`` (PRB plant) or on the observed angles and rates (any plant, designed on
the condensed model); cost ``y' Q_y y + R tau^2`` by Bryson's rule on ``y = [theta, phi, theta_dot, phi_dot]``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from softpend.checks import non_negative, one_of, positive
from softpend.control.linearise import (
    LinearModel,
    discretise,
    linearise_exudyn,
    observation_coordinates_matrix,
    reduce_to_observation_coordinates,
)
from softpend.plant import Observation, RodParams, wrap_angle_rad

StateFunction = Callable[[Observation, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class LQRWeights:
    """Bryson's-rule tolerances of ``y`` and the torque; ``regularisation`` (relative to ``Q``'s largest
    diagonal entry) is added to ``Q``'s diagonal."""

    theta_max_rad: float = 0.01
    phi_max_rad: float = 0.5
    theta_dot_max_rad_s: float = 2.0
    phi_dot_max_rad_s: float = 10.0
    torque_max_nm: float = RodParams.torque_limit_nm
    regularisation: float = 1e-6

    def __post_init__(self) -> None:
        for name in ("theta_max_rad", "phi_max_rad", "theta_dot_max_rad_s", "phi_dot_max_rad_s", "torque_max_nm"):
            positive(name, getattr(self, name))
        non_negative("regularisation", self.regularisation)

    @property
    def r(self) -> float:
        return 1.0 / self.torque_max_nm**2


def output_weight_matrix(output_map: np.ndarray, weights: LQRWeights) -> np.ndarray:
    """``Q = C_y' Q_y C_y + eps I`` for outputs ``y = C_y x`` (``output_map`` is ``C_y``, shape ``(4, nx)``)."""
    c = np.asarray(output_map, dtype=float)
    if c.ndim != 2 or c.shape[0] != 4:
        raise ValueError(f"output_map must have shape (4, n_states), got {c.shape}")
    w = weights
    tolerances = np.array([w.theta_max_rad, w.phi_max_rad, w.theta_dot_max_rad_s, w.phi_dot_max_rad_s])
    q = c.T @ np.diag(1.0 / tolerances**2) @ c
    return q + weights.regularisation * float(np.max(np.diag(q))) * np.eye(c.shape[1])


def design_lqr(model: LinearModel, q: np.ndarray, r: float) -> np.ndarray:
    """Optimal gain ``K`` (``u = -K x``); ``ValueError`` if the Riccati equation has no stabilising solution."""
    import control

    q = np.asarray(q, dtype=float)
    if q.shape != (model.n_states, model.n_states):
        raise ValueError(f"q must have shape {(model.n_states, model.n_states)}, got {q.shape}")
    positive("r", r)
    solve = control.dlqr if model.is_discrete else control.lqr
    try:
        gain, _, _ = solve(model.a, model.b, q, np.array([[r]]))
    except Exception as exc:  # python-control raises several types for a failed Riccati solve
        raise ValueError(f"LQR design failed: {exc}") from exc
    return np.asarray(gain, dtype=float).reshape(1, -1)


def _joint_state(observation: Observation, q: np.ndarray, q_dot: np.ndarray) -> np.ndarray:
    q = np.array(q, dtype=float)
    q[0] = wrap_angle_rad(float(q[0]))
    return np.concatenate([q, np.asarray(q_dot, dtype=float)])


def observation_state_function(names: tuple[str, ...]) -> StateFunction:
    """State ``[angles..., rates...]`` read from an :class:`Observation`."""
    rate_names = tuple(name.replace("_rad", "_dot_rad_s") for name in names)

    def state(observation: Observation, q: np.ndarray, q_dot: np.ndarray) -> np.ndarray:
        return np.array([getattr(observation, n) for n in names] + [getattr(observation, n) for n in rate_names])

    return state


class LQRController:
    """State feedback ``tau = sat(-K x)``, ``x = state_function(observation, q, q_dot)`` (deviation from upright;
    its ``reset()``, if any, called by :meth:`reset`); ``model`` is the design model."""

    def __init__(
        self,
        gain: np.ndarray,
        state_function: StateFunction,
        torque_limit_nm: float,
        model: Optional[LinearModel] = None,
        name: str = "LQR",
    ) -> None:
        gain = np.asarray(gain, dtype=float).reshape(1, -1)
        if not np.all(np.isfinite(gain)):
            raise ValueError("gain must be finite")
        positive("torque_limit_nm", torque_limit_nm)
        if model is not None and model.n_states != gain.shape[1]:
            raise ValueError(f"gain has {gain.shape[1]} columns but the model has {model.n_states} states")
        self.gain, self.state_function, self.torque_limit_nm = gain, state_function, float(torque_limit_nm)
        self.model, self.name = model, name

    @classmethod
    def from_params(
        cls,
        params: Optional[RodParams] = None,
        dt_s: float = 0.01,
        state: str = "joint",
        weights: Optional[LQRWeights] = None,
        torque_limit_nm: Optional[float] = None,
    ) -> "LQRController":
        """Discrete LQR designed on Exudyn's linearisation of the PRB model of ``params`` (condensed onto the
        observed angles for ``"observation"`` feedback), on ``"joint"`` or ``"observation"`` feedback."""
        params = params if params is not None else RodParams()
        weights = weights if weights is not None else LQRWeights()
        limit = params.torque_limit_nm if torque_limit_nm is None else torque_limit_nm
        one_of("state", state, ("joint", "observation"))
        state_function: StateFunction
        if state == "joint":
            model = discretise(linearise_exudyn(params).state_space(), dt_s)
            angles = observation_coordinates_matrix(params, ("theta_rad", "phi_rad"))
            state_function, name = _joint_state, "LQR (joint state)"
        else:
            reduced, _, names = reduce_to_observation_coordinates(linearise_exudyn(params), params)
            model = discretise(reduced.state_space(), dt_s)
            rates = tuple(n.replace("_rad", "_dot_rad_s") for n in names)
            model = LinearModel(model.a, model.b, model.dt_s, names + rates)
            angles = np.eye(len(names))[[names.index("theta_rad"), names.index("phi_rad")]]
            state_function, name = observation_state_function(names), "LQR (observations)"
        zero = np.zeros_like(angles)
        q = output_weight_matrix(np.block([[angles, zero], [zero, angles]]), weights)
        return cls(design_lqr(model, q, weights.r), state_function, limit, model=model, name=name)

    def reset(self) -> None:
        getattr(self.state_function, "reset", lambda: None)()

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        torque = -float(self.gain[0] @ self.state_function(observation, q, q_dot))
        return min(max(torque, -self.torque_limit_nm), self.torque_limit_nm)

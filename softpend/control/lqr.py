"""Linear-quadratic regulators about upright (python-control), applied with saturation.

Feedback on the joint state ``[q, q_dot]`` (PRB plant) or on the observed angles and rates (any plant, designed on
the condensed model); cost ``y' Q_y y + R tau^2`` by Bryson's rule on ``y = [theta, phi, theta_dot, phi_dot]``.
"""

from __future__ import annotations

from typing import Callable, Optional

import numpy as np

from softpend.checks import one_of, positive
from softpend.control.linearise import (
    LinearModel,
    discretise,
    linearise_exudyn,
    observation_coordinates_matrix,
    reduce_to_observation_coordinates,
)
from softpend.plant import Observation, RodParams, wrap_angle_rad

StateFunction = Callable[[Observation, np.ndarray, np.ndarray], np.ndarray]


#: Bryson's-rule tolerances of ``y = [theta, phi, theta_dot, phi_dot]`` [rad, rad/s]: ``Q_y`` their inverse squares.
OUTPUT_TOLERANCES = np.array([0.01, 0.5, 2.0, 10.0])
#: ``R``: the inverse square of the torque tolerance, the default rod's torque limit.
TORQUE_WEIGHT = 1.0 / RodParams.torque_limit_nm**2
#: Added to ``Q``'s diagonal, relative to its largest diagonal entry.
REGULARISATION = 1e-6


def output_weight_matrix(output_map: np.ndarray) -> np.ndarray:
    """``Q = C_y' Q_y C_y + eps I`` for outputs ``y = C_y x`` (``output_map`` is ``C_y``, shape ``(4, nx)``)."""
    c = np.asarray(output_map, dtype=float)
    q = c.T @ np.diag(1.0 / OUTPUT_TOLERANCES**2) @ c
    return q + REGULARISATION * float(np.max(np.diag(q))) * np.eye(c.shape[1])


def design_lqr(model: LinearModel, q: np.ndarray, r: float) -> np.ndarray:
    """Optimal gain ``K`` (``u = -K x``); ``ValueError`` if the Riccati equation has no stabilising solution."""
    import control

    solve = control.lqr if model.dt_s is None else control.dlqr
    try:
        gain, _, _ = solve(model.a, model.b, q, np.array([[r]]))
    except Exception as exc:  # python-control raises several types for a failed Riccati solve
        raise ValueError(f"LQR design failed: {exc}") from exc
    return np.asarray(gain, dtype=float).reshape(1, -1)


def _joint_state(observation: Observation, q: np.ndarray, q_dot: np.ndarray) -> np.ndarray:
    q = np.array(q, dtype=float)
    q[0] = wrap_angle_rad(float(q[0]))
    return np.concatenate([q, np.asarray(q_dot, dtype=float)])


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
        self.gain, self.state_function, self.torque_limit_nm = gain, state_function, float(torque_limit_nm)
        self.model, self.name = model, name

    @classmethod
    def from_params(
        cls,
        params: Optional[RodParams] = None,
        dt_s: float = 0.01,
        state: str = "joint",
        torque_limit_nm: Optional[float] = None,
    ) -> "LQRController":
        """Discrete LQR designed on Exudyn's linearisation of the PRB model of ``params`` (condensed onto the
        observed angles for ``"observation"`` feedback), on ``"joint"`` or ``"observation"`` feedback."""
        params = params if params is not None else RodParams()
        limit = params.torque_limit_nm if torque_limit_nm is None else torque_limit_nm
        one_of("state", state, ("joint", "observation"))
        positive("dt_s", dt_s)
        state_function: StateFunction
        if state == "joint":
            model = discretise(linearise_exudyn(params).state_space(), dt_s)
            angles = observation_coordinates_matrix(params, ("theta_rad", "phi_rad"))
            state_function, name = _joint_state, "LQR (joint state)"
        else:
            reduced, _, names = reduce_to_observation_coordinates(linearise_exudyn(params), params)
            model = discretise(reduced.state_space(), dt_s)
            observed = names + tuple(n.replace("_rad", "_dot_rad_s") for n in names)  # the angles, then their rates
            model = LinearModel(model.a, model.b, model.dt_s, observed)
            angles = np.eye(len(names))[[names.index("theta_rad"), names.index("phi_rad")]]
            state_function = lambda o, q, q_dot: np.array([getattr(o, n) for n in observed])  # noqa: E731
            name = "LQR (observations)"
        zero = np.zeros_like(angles)
        q = output_weight_matrix(np.block([[angles, zero], [zero, angles]]))
        return cls(design_lqr(model, q, TORQUE_WEIGHT), state_function, limit, model=model, name=name)

    def reset(self) -> None:
        getattr(self.state_function, "reset", lambda: None)()

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        torque = -float(self.gain[0] @ self.state_function(observation, q, q_dot))
        return min(max(torque, -self.torque_limit_nm), self.torque_limit_nm)

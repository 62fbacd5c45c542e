"""Linear-quadratic regulators about upright, designed with python-control, applied with saturation.

Two feedback paths, both designed on the PRB model built from :class:`~softpend.plant.RodParams`:

* **joint state** (:meth:`LQRController.from_params` with ``state="joint"``): ``x = [q, q_dot]`` with the
  hub angle wrapped to ``[-pi, pi)``.  Needs the plant's joint state (the PRB plant; ideal sensing).
* **observations** (``state="observation"``): ``z = [phi, theta, e_r, phi_dot, theta_dot, e_r_dot]`` read
  from the report's observed variables only, so it runs on any plant (e.g. the continuum beam).  The design
  model is the joint-space model condensed onto these coordinates
  (:func:`~softpend.control.linearise.reduce_to_observation_coordinates`).

The gain of the learned dynamics model is built in :mod:`softpend.control.learned`, also as an
:class:`LQRController`.

Cost (Bryson's rule, :class:`LQRWeights`)
-----------------------------------------
``J = sum_k y_k' Q_y y_k + R tau_k^2`` with ``y = [theta, phi, theta_dot, phi_dot]`` and
``Q_y = diag(1/theta_max^2, 1/phi_max^2, 1/theta_dot_max^2, 1/phi_dot_max^2)``, ``R = 1/tau_max^2``.
The tolerances are the fields of :class:`LQRWeights` (the tip angle tightest, the hub angle loosest, ``tau_max``
the default torque limit).  The bending coordinates get no direct weight; a small ``regularisation`` on the whole
state keeps ``Q`` positive definite.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from softpend.checks import non_negative, positive
from softpend.control.linearise import (
    LinearModel,
    discretise,
    linearise_exudyn,
    linearise_step_map,
    observation_coordinates_matrix,
    reduce_to_observation_coordinates,
)
from softpend.plant import Observation, RodParams, wrap_angle_rad

__all__ = ["LQRController", "LQRWeights", "design_lqr", "output_weight_matrix"]

StateFunction = Callable[[Observation, np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class LQRWeights:
    """Bryson's-rule tolerances that define ``Q`` and ``R`` (see the module docstring).

    Attributes
    ----------
    theta_max_rad : float
        Acceptable tip-angle excursion [rad].
    phi_max_rad : float
        Acceptable hub-angle excursion [rad].
    theta_dot_max_rad_s, phi_dot_max_rad_s : float
        Acceptable rates [rad/s].
    torque_max_nm : float
        Acceptable torque [N m] (``R = 1/torque_max_nm**2``).
    regularisation : float
        Added to every diagonal entry of ``Q`` (relative to the largest entry).
    """

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

    def output_weights(self) -> np.ndarray:
        """``diag(Q_y)`` for ``y = [theta, phi, theta_dot, phi_dot]``."""
        return (
            1.0
            / np.array([self.theta_max_rad, self.phi_max_rad, self.theta_dot_max_rad_s, self.phi_dot_max_rad_s]) ** 2
        )

    @property
    def r(self) -> float:
        return 1.0 / self.torque_max_nm**2


def output_weight_matrix(output_map: np.ndarray, weights: LQRWeights) -> np.ndarray:
    """``Q = C_y' Q_y C_y + eps I`` for a state whose outputs ``y = [theta, phi, theta_dot, phi_dot]`` are
    ``y = C_y x`` (``output_map`` is ``C_y``, shape ``(4, nx)``)."""
    c = np.asarray(output_map, dtype=float)
    if c.ndim != 2 or c.shape[0] != 4:
        raise ValueError(f"output_map must have shape (4, n_states), got {c.shape}")
    q = c.T @ np.diag(weights.output_weights()) @ c
    return q + weights.regularisation * float(np.max(np.diag(q))) * np.eye(c.shape[1])


def design_lqr(model: LinearModel, q: np.ndarray, r: float) -> np.ndarray:
    """Optimal gain ``K`` (``u = -K x``) from ``control.dlqr`` (discrete model) or ``control.lqr``.

    Raises
    ------
    ValueError
        If the weights have the wrong shape or the Riccati equation has no stabilising solution.
    """
    import control

    q = np.asarray(q, dtype=float)
    if q.shape != (model.n_states, model.n_states):
        raise ValueError(f"q must have shape {(model.n_states, model.n_states)}, got {q.shape}")
    positive("r", r)
    try:
        if model.is_discrete:
            gain, _, _ = control.dlqr(model.a, model.b, q, np.array([[r]]))
        else:
            gain, _, _ = control.lqr(model.a, model.b, q, np.array([[r]]))
    except Exception as exc:  # python-control raises several types for a failed Riccati solve
        raise ValueError(f"LQR design failed: {exc}") from exc
    return np.asarray(gain, dtype=float).reshape(1, -1)


def _joint_state(observation: Observation, q: np.ndarray, q_dot: np.ndarray) -> np.ndarray:
    q = np.array(q, dtype=float)
    q[0] = wrap_angle_rad(float(q[0]))
    return np.concatenate([q, np.asarray(q_dot, dtype=float)])


def observation_state_function(names: tuple[str, ...]) -> StateFunction:
    """State ``[angles..., rates...]`` read from an :class:`Observation` (names from
    :data:`~softpend.control.linearise.OBSERVATION_COORDINATE_NAMES`); angles are already wrapped."""
    rate_names = tuple(name.replace("_rad", "_dot_rad_s") for name in names)

    def state(observation: Observation, q: np.ndarray, q_dot: np.ndarray) -> np.ndarray:
        return np.array([getattr(observation, n) for n in names] + [getattr(observation, n) for n in rate_names])

    return state


class LQRController:
    """State feedback ``tau = sat(-K x)`` with ``x`` built from the observation and/or joint state.

    Parameters
    ----------
    gain : (1, nx) array
        LQR gain ``K``.
    state_function : callable
        ``state_function(observation, q, q_dot) -> x`` (deviation from upright).
    torque_limit_nm : float
        Saturation applied to the commanded torque [N m] (the plant saturates too; this keeps the
        commanded and applied torques equal).
    model : LinearModel, optional
        The design model (kept for analysis: closed-loop eigenvalues).
    name : str
        Label for tables.
    """

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
        self.gain = gain
        self.state_function = state_function
        self.torque_limit_nm = float(torque_limit_nm)
        self.model = model
        self.name = name

    # ------------------------------------------------------------------ constructors
    @classmethod
    def from_params(
        cls,
        params: Optional[RodParams] = None,
        dt_s: float = 0.01,
        state: str = "joint",
        weights: Optional[LQRWeights] = None,
        torque_limit_nm: Optional[float] = None,
        linearisation: str = "exudyn",
        substeps: int = 2,
    ) -> "LQRController":
        """LQR designed on the PRB model of ``params`` (the "true model").

        Parameters
        ----------
        params : RodParams, optional
            Rod and hub (default rod).  For a beam plant pass the beam's ``RodParams``: the design uses
            the PRB chain with ``params.n_links`` links.
        dt_s : float
            Control step [s]; the design is discrete (zero-order hold).
        state : {"joint", "observation"}
            Feedback path (see the module docstring).
        weights : LQRWeights, optional
            Cost tolerances (defaults documented on :class:`LQRWeights`).
        torque_limit_nm : float, optional
            Saturation [N m] (default ``params.torque_limit_nm``).
        linearisation : {"exudyn", "step_map"}
            Joint-state design model: Exudyn's linearised matrices discretised with ZOH, or finite
            differences of the simulator's step map (only for ``state="joint"``).
        substeps : int
            Solver sub-steps of the step-map linearisation.
        """
        params = params if params is not None else RodParams()
        weights = weights if weights is not None else LQRWeights()
        limit = params.torque_limit_nm if torque_limit_nm is None else torque_limit_nm
        if state not in ("joint", "observation"):
            raise ValueError(f"state must be 'joint' or 'observation', got {state!r}")
        if linearisation not in ("exudyn", "step_map"):
            raise ValueError(f"linearisation must be 'exudyn' or 'step_map', got {linearisation!r}")
        mechanics = linearise_exudyn(params)
        if state == "joint":
            if linearisation == "exudyn":
                model = discretise(mechanics.state_space(), dt_s)
            else:
                model = linearise_step_map(params, dt_s=dt_s, substeps=substeps)
            n = params.n_links + 1
            angles = observation_coordinates_matrix(params, ("theta_rad", "phi_rad"))
            zero = np.zeros_like(angles)
            output_map = np.block([[angles, zero], [zero, angles]])
            q = output_weight_matrix(output_map, weights)
            gain = design_lqr(model, q, weights.r)
            assert gain.shape == (1, 2 * n)
            return cls(gain, _joint_state, limit, model=model, name="LQR (joint state)")
        if linearisation != "exudyn":
            raise ValueError("state='observation' uses the condensed Exudyn model; use linearisation='exudyn'")
        reduced, _, names = reduce_to_observation_coordinates(mechanics, params)
        model = discretise(reduced.state_space(), dt_s)
        model = LinearModel(model.a, model.b, model.dt_s, names + tuple(n.replace("_rad", "_dot_rad_s") for n in names))
        k = len(names)
        select = np.zeros((2, k))
        select[0, names.index("theta_rad")] = 1.0
        select[1, names.index("phi_rad")] = 1.0
        zero = np.zeros_like(select)
        output_map = np.block([[select, zero], [zero, select]])
        q = output_weight_matrix(output_map, weights)
        gain = design_lqr(model, q, weights.r)
        return cls(gain, observation_state_function(names), limit, model=model, name="LQR (observations)")

    # ------------------------------------------------------------------ Controller protocol
    def reset(self) -> None:
        """Stateless: nothing to clear."""

    def state(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray) -> np.ndarray:
        """The feedback state ``x`` for the current step."""
        return self.state_function(observation, q, q_dot)

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray, time_s: float) -> float:
        torque = -float(self.gain[0] @ self.state(observation, q, q_dot))
        return min(max(torque, -self.torque_limit_nm), self.torque_limit_nm)

    def closed_loop_eigenvalues(self, model: Optional[LinearModel] = None) -> np.ndarray:
        """Eigenvalues of ``A - B K`` on ``model`` (default: the design model)."""
        model = model if model is not None else self.model
        if model is None:
            raise ValueError("no model given and the controller has no design model")
        return np.linalg.eigvals(model.closed_loop(self.gain))

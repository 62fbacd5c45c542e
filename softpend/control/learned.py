"""Classical designs on the learned dynamics model (the report's suggestion): linearisation, LQR, PID tuning.

The learned model (:class:`softpend.sysid.DynamicsModel` or an ensemble; anything with ``layout``,
``dt_s`` and ``predict_next(state (B, d), torque_nm (B,)) -> (B, d)``) predicts the next *observed* state
in the layout :mod:`softpend.sysid.layout` describes (full information: the report's observed variables;
limited: hub angle and tip position with lagged frames).  Here:

* :func:`upright_state_vector` builds the model's state of the straight rod at rest upright;
* :func:`linearise_learned_model` gives ``x+ = A x + B tau`` at that state by autograd
  (``torch.autograd.functional.jacobian`` in float64);
* :func:`lqr_from_learned_model` designs a discrete LQR on it with the same Bryson weights as the
  true-model design, and returns an :class:`~softpend.control.lqr.LQRController` whose state is built
  from observations exactly as the model's state is (backward-difference velocities when the model was
  trained on them, lagged frames);
* :func:`learned_model_simulator` rolls a controller out on the model, for :func:`softpend.control.pid.tune_pid`.
"""

from __future__ import annotations

import copy
import math
from typing import Any, Optional

import numpy as np

from softpend.control.linearise import LinearModel
from softpend.control.lqr import LQRController, LQRWeights, design_lqr, output_weight_matrix
from softpend.plant import OBSERVATION_NAMES, Observation, PRBPlant, RodParams

__all__ = [
    "LearnedStateTracker",
    "learned_model_simulator",
    "linearise_learned_model",
    "lqr_from_learned_model",
    "reduce_learned_model",
    "reduced_coordinate_names",
    "reduction_matrices",
    "upright_state_vector",
]


def _base_name(name: str) -> str:
    return name.split("_lag")[0]


def upright_state_vector(model: Any, params: RodParams) -> np.ndarray:
    """The model's state vector for the straight rod at rest upright (lags equal to the current frame)."""
    plant = PRBPlant(params)
    observation = plant.reset()
    values = dict(zip(OBSERVATION_NAMES, observation.as_array()))
    try:
        return np.array([values[_base_name(name)] for name in model.layout.names])
    except KeyError as exc:
        raise ValueError(f"model state entry {exc} is not an observed variable") from exc


def linearise_learned_model(
    model: Any, params: Optional[RodParams] = None, state: Optional[np.ndarray] = None, torque_nm: float = 0.0
) -> LinearModel:
    """Jacobians ``A = d f / d x``, ``B = d f / d tau`` of the learned one-step map at upright (autograd).

    Parameters
    ----------
    model : DynamicsModel or DynamicsEnsemble (or any module with ``layout``, ``dt_s``, ``predict_next``)
        An ensemble is linearised through its mean prediction.
    params : RodParams, optional
        Rod geometry used to build the upright state (default rod).
    state : array (d,), optional
        Linearisation point instead of upright.
    torque_nm : float
        Torque at the linearisation point [N m].
    """
    import torch

    params = params if params is not None else RodParams()
    x0 = upright_state_vector(model, params) if state is None else np.asarray(state, dtype=float)
    if x0.shape != (len(model.layout.names),):
        raise ValueError(f"state must have shape ({len(model.layout.names)},), got {x0.shape}")
    net = copy.deepcopy(model).double().eval()
    members = list(net.members) if hasattr(net, "members") else [net]

    def step(x: "torch.Tensor", u: "torch.Tensor") -> "torch.Tensor":
        outs = [m.predict_next(x.reshape(1, -1), u.reshape(1)) for m in members]
        return torch.stack(outs).mean(dim=0).reshape(-1)

    x = torch.as_tensor(x0, dtype=torch.float64)
    u = torch.tensor([float(torque_nm)], dtype=torch.float64)
    a, b = torch.autograd.functional.jacobian(step, (x, u))
    return LinearModel(
        a=a.detach().numpy(),
        b=b.detach().numpy().reshape(-1, 1),
        dt_s=float(model.dt_s),
        state_names=tuple(model.layout.names),
    )


def _output_map(names: tuple[str, ...], params: RodParams) -> np.ndarray:
    """Rows ``[theta, phi, theta_dot, phi_dot]`` as linear functions of the model state at upright
    (``theta ~ -ex / L`` when the model has the tip position but not ``theta``)."""
    c = np.zeros((4, len(names)))
    for row, angle in ((0, "theta"), (1, "phi")):
        for offset, suffix in ((0, "_rad"), (2, "_dot_rad_s")):
            name = angle + suffix
            if name in names:
                c[row + offset, names.index(name)] = 1.0
            elif angle == "theta":
                ex = "ex_m" if offset == 0 else "ex_dot_m_s"
                if ex not in names:
                    raise ValueError(f"the model state has neither {name} nor {ex}")
                c[row + offset, names.index(ex)] = -1.0 / params.length_m
            else:
                raise ValueError(f"the model state has no {name}")
    return c


def velocity_name(position_name: str) -> str:
    """Observed rate belonging to a position variable (``phi_rad -> phi_dot_rad_s``, ``ex_m -> ex_dot_m_s``)."""
    from softpend.sysid.variables import velocity_name as name

    return name(position_name)


class LearnedStateTracker:
    """Builds the learned model's state vector from successive observations, as the training data did:
    positions as observed, velocities as backward differences of the unwrapped positions (or the
    observation's rates for a model trained on true velocities), lagged frames from a short history."""

    def __init__(self, model: Any) -> None:
        layout = model.layout
        self.names = tuple(layout.names)
        self.dt_s = float(model.dt_s)
        self.positions = tuple(layout.position_names)
        self.history = int(layout.history)
        self.differenced = getattr(layout, "velocity_source", "observed") == "observed"
        self.reset()

    def reset(self) -> None:
        self._frames: list[np.ndarray] = []

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray) -> np.ndarray:
        values = dict(zip(OBSERVATION_NAMES, observation.as_array()))
        frame = np.array([values[n] for n in self.positions])
        if self.differenced and self._frames:
            step = frame - self._frames[-1]
            for i, name in enumerate(self.positions):
                if name.endswith("_rad"):
                    step[i] = (step[i] + math.pi) % (2 * math.pi) - math.pi
            rates = step / self.dt_s
        else:
            rates = np.array([values[velocity_name(n)] for n in self.positions])
        lags = [self._frames[-k] if len(self._frames) >= k else frame for k in range(1, self.history + 1)]
        self._frames.append(frame)
        del self._frames[: -max(self.history, 1)]
        return np.concatenate([frame, rates] + lags)


class _TrackedLQR(LQRController):
    """LQR whose state tracker must be reset with the controller."""

    def __init__(
        self,
        gain: np.ndarray,
        torque_limit_nm: float,
        *,
        tracker: LearnedStateTracker,
        upright: np.ndarray,
        model: LinearModel,
        name: str,
        design_model: LinearModel,
        design_gain: np.ndarray,
    ) -> None:
        self.tracker = tracker
        self.upright = upright
        #: the (possibly reduced) model the Riccati equation was solved on, and the gain on its state
        self.design_model = design_model
        self.design_gain = np.asarray(design_gain, dtype=float).reshape(1, -1)
        super().__init__(gain, self._state, torque_limit_nm, model=model, name=name)

    def _state(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray) -> np.ndarray:
        return self.tracker(observation, q, q_dot) - self.upright

    def reset(self) -> None:
        self.tracker.reset()


def reduced_coordinate_names(names: tuple[str, ...]) -> tuple[str, ...]:
    """Angles of the reduced learned model: hub angle, tip angle and, when the model observes it, tip
    rotation (full information); the state is these angles followed by their rates."""
    return ("phi_rad", "theta_rad", "er_rad") if "er_rad" in names else ("phi_rad", "theta_rad")


def reduction_matrices(
    names: tuple[str, ...], params: RodParams, dt_s: float
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """Maps between the learned model's state ``x`` and ``z = [angles, rates]`` about upright.

    The angles are :func:`reduced_coordinate_names`.  ``P`` embeds ``z`` to first order: ``ex = -L theta``,
    ``ey`` unchanged, ``e_r = theta`` when the model has no ``e_r`` coordinate of its own, rates alike, and a
    frame lagged by ``k`` steps at ``position - k dt rate``.  ``S`` reads ``z`` back from ``x``
    (``theta = -ex/L`` for a model without ``theta``).  ``S P = I``.

    Returns
    -------
    S : (2k, d) array
    P : (d, 2k) array
    z_names : tuple of str
    """
    angles = reduced_coordinate_names(names)
    k = len(angles)
    length = params.length_m
    embed = {name: np.eye(k)[i] for i, name in enumerate(angles)}
    embed.setdefault("er_rad", embed["theta_rad"])
    embed["ex_m"] = -length * embed["theta_rad"]
    embed["ey_m"] = np.zeros(k)
    p = np.zeros((len(names), 2 * k))
    for i, name in enumerate(names):
        base, _, lag = name.partition("_lag")
        lag_steps = int(lag) if lag else 0
        rate_of = {velocity_name(position): position for position in embed}
        if base in rate_of:
            p[i, k:] = embed[rate_of[base]]
        elif base in embed:
            p[i, :k] = embed[base]
            p[i, k:] = -lag_steps * dt_s * embed[base]
        else:
            raise ValueError(f"model state entry {name!r} is not an observed variable")
    s = np.zeros((2 * k, len(names)))
    for offset, to_name in ((0, lambda a: a), (k, velocity_name)):
        for j, angle in enumerate(angles):
            name = to_name(angle)
            if name in names:
                s[offset + j, names.index(name)] = 1.0
            else:  # theta from the tip position
                s[offset + j, names.index(to_name("ex_m"))] = -1.0 / length
    z_names = angles + tuple(velocity_name(a) for a in angles)
    return s, p, z_names


def reduce_learned_model(model_lin: LinearModel, params: RodParams) -> tuple[LinearModel, np.ndarray]:
    """Project the learned linearisation onto ``z`` (:func:`reduction_matrices`): ``A_z = S A P``, ``B_z = S B``.

    Returns the reduced model and ``S``.

    The observed variables are redundant (``ex`` and ``theta`` carry the same first-order information,
    ``ey`` none), and a network's Jacobian along such directions is unconstrained by the data; the
    projection keeps the dynamics the data does constrain.
    """
    assert model_lin.dt_s is not None  # a learned model is discrete-time
    s, p, z_names = reduction_matrices(model_lin.state_names, params, model_lin.dt_s)
    reduced = LinearModel(a=s @ model_lin.a @ p, b=s @ model_lin.b, dt_s=model_lin.dt_s, state_names=z_names)
    return reduced, s


def lqr_from_learned_model(
    model: Any,
    params: Optional[RodParams] = None,
    weights: Optional[LQRWeights] = None,
    torque_limit_nm: Optional[float] = None,
    reduced: bool = True,
) -> LQRController:
    """Discrete LQR designed on the autograd linearisation of the learned model.

    ``Q`` penalises ``[theta, phi, theta_dot, phi_dot]`` (same :class:`~softpend.control.lqr.LQRWeights` as
    the true-model design).  With ``reduced=True`` (default) the design model is the linearisation
    projected onto ``z = [phi, theta, (e_r,) rates]`` (:func:`reduce_learned_model`) and the feedback is
    ``z`` read from the model's state; with ``reduced=False`` the design uses the model's full state
    (redundant directions included, which a network leaves unconstrained, so the Riccati solve may fail or
    give large gains).  The model's state is built from observations as in training
    (:class:`LearnedStateTracker`), minus its upright value.

    Raises
    ------
    ValueError
        If the learned linearisation is not stabilisable with these weights.
    """
    params = params if params is not None else RodParams()
    weights = weights if weights is not None else LQRWeights()
    model_lin = linearise_learned_model(model, params)
    limit = params.torque_limit_nm if torque_limit_nm is None else torque_limit_nm
    if reduced:
        design, select = reduce_learned_model(model_lin, params)
        z = design.state_names
        output_map = np.zeros((4, len(z)))  # y = [theta, phi, theta_dot, phi_dot] from z
        for row, name in enumerate(("theta_rad", "phi_rad", "theta_dot_rad_s", "phi_dot_rad_s")):
            output_map[row, z.index(name)] = 1.0
    else:
        design, select = model_lin, np.eye(model_lin.n_states)
        output_map = _output_map(model_lin.state_names, params)
    q = output_weight_matrix(output_map, weights)
    design_gain = design_lqr(design, q, weights.r)
    return _TrackedLQR(
        design_gain @ select,
        limit,
        model=model_lin,
        name="LQR (learned model)",
        tracker=LearnedStateTracker(model),
        upright=upright_state_vector(model, params),
        design_model=design,
        design_gain=design_gain,
    )


def learned_model_simulator(model: Any, params: Optional[RodParams] = None):
    """``simulate(controller, tilt_rad, duration_s) -> (theta_rad, torque_nm)`` on the learned model.

    The start is the straight rod at rest tilted by ``tilt_rad`` (as on the true plant), converted to the
    model's state; each step the controller sees an :class:`Observation` rebuilt from the predicted state
    (tip angle from the tip position, ``theta = atan2(-ex, ey)``; missing rates are backward differences)
    and the torque, saturated at the controller's limit, is fed to ``predict_next``.
    """
    import torch

    params = params if params is not None else RodParams()
    names = tuple(model.layout.names)
    net = model.eval()
    dt_s = float(model.dt_s)

    def to_observation(x: np.ndarray, previous: Optional[dict[str, float]]) -> tuple[Observation, dict[str, float]]:
        v = {name: float(value) for name, value in zip(names, x) if "_lag" not in name}
        ex, ey = v["ex_m"], v["ey_m"]
        theta = math.atan2(-ex, ey)
        v.setdefault("theta_rad", theta)
        v.setdefault("er_rad", theta)
        for angle in ("theta_rad", "er_rad"):
            rate = angle.replace("_rad", "_dot_rad_s")
            if rate not in v:
                v[rate] = (
                    0.0
                    if previous is None
                    else ((v[angle] - previous[angle] + math.pi) % (2 * math.pi) - math.pi) / dt_s
                )
        observation = Observation(*[v[name] for name in OBSERVATION_NAMES])
        return observation, v

    def simulate(controller: Any, tilt_rad: float, duration_s: float) -> tuple[np.ndarray, np.ndarray]:
        plant = PRBPlant(params, dt_s=dt_s)
        q = np.zeros(plant.n_coordinates)
        q[0] = tilt_rad
        start = plant.reset(q, np.zeros_like(q))
        values = dict(zip(OBSERVATION_NAMES, start.as_array()))
        x = np.array([values[_base_name(name)] for name in names])
        n_steps = int(round(duration_s / dt_s))
        thetas, torques = np.empty(n_steps + 1), np.zeros(n_steps + 1)
        observation, previous = to_observation(x, None)
        thetas[0] = observation.theta_rad
        limit = float(getattr(controller, "torque_limit_nm", params.torque_limit_nm))
        with torch.no_grad():
            for k in range(n_steps):
                torque = min(max(float(controller(observation, None, None, k * dt_s)), -limit), limit)
                torques[k] = torque
                x = (
                    net.predict_next(
                        torch.as_tensor(x, dtype=torch.float32).reshape(1, -1),
                        torch.tensor([torque], dtype=torch.float32),
                    )
                    .reshape(-1)
                    .double()
                    .numpy()
                )
                if not np.all(np.isfinite(x)):
                    thetas[k + 1 :] = np.nan
                    break
                observation, previous = to_observation(x, previous)
                thetas[k + 1] = observation.theta_rad
        return thetas, torques

    return simulate

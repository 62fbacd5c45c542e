"""Classical designs on a learned dynamics model (anything with ``layout``, ``dt_s`` and ``predict_next``):
its autograd linearisation at upright, an LQR on it, and closed-loop rollouts on the model for PID tuning."""

from __future__ import annotations

import copy
import math
from typing import Any, Optional

import numpy as np

from softpend.control.linearise import LinearModel
from softpend.control.lqr import TORQUE_WEIGHT, LQRController, design_lqr, output_weight_matrix
from softpend.plant import OBSERVATION_NAMES, Observation, PRBPlant, RodParams, tilt_state
from softpend.sysid.variables import velocity_name


def _state_vector(names: tuple[str, ...], observation: Observation) -> np.ndarray:
    """The model state of an observation with every lagged frame equal to it."""
    values = dict(zip(OBSERVATION_NAMES, observation.as_array()))
    return np.array([values[name.split("_lag")[0]] for name in names])


def upright_state_vector(model: Any, params: RodParams) -> np.ndarray:
    """The model's state of the straight rod at rest upright."""
    return _state_vector(tuple(model.layout.names), PRBPlant(params).reset())


def linearise_learned_model(model: Any, params: Optional[RodParams] = None) -> LinearModel:
    """Jacobians ``A``, ``B`` of the model's one-step map (an ensemble's mean) at upright at rest, no torque."""
    import torch

    x0 = upright_state_vector(model, params if params is not None else RodParams())
    net = copy.deepcopy(model).double().eval()
    members = list(net.members) if hasattr(net, "members") else [net]

    def step(x: "torch.Tensor", u: "torch.Tensor") -> "torch.Tensor":
        outs = [m.predict_next(x.reshape(1, -1), u.reshape(1)) for m in members]
        return torch.stack(outs).mean(dim=0).reshape(-1)

    x = torch.as_tensor(x0, dtype=torch.float64)
    u = torch.tensor([0.0], dtype=torch.float64)
    a, b = torch.autograd.functional.jacobian(step, (x, u))
    b = b.detach().numpy().reshape(-1, 1)
    return LinearModel(a=a.detach().numpy(), b=b, dt_s=float(model.dt_s), state_names=tuple(model.layout.names))


class LearnedStateTracker:
    """The model's state from successive observations as in its training data: positions, their rates
    (backward differences of the unwrapped positions, or the observed rates) and lagged frames, minus ``offset``."""

    def __init__(self, model: Any, offset: Any = 0.0) -> None:
        layout, self.offset = model.layout, offset
        self.dt_s, self.positions, self.history = float(model.dt_s), tuple(layout.position_names), int(layout.history)
        self.differenced = getattr(layout, "velocity_source", "observed") == "observed"
        self.reset()

    def reset(self) -> None:
        self._frames: list[np.ndarray] = []

    def __call__(self, observation: Observation, q: np.ndarray, q_dot: np.ndarray) -> np.ndarray:
        values = dict(zip(OBSERVATION_NAMES, observation.as_array()))
        frame = np.array([values[n] for n in self.positions])
        if self.differenced and self._frames:
            step = frame - self._frames[-1]
            angles = [name.endswith("_rad") for name in self.positions]
            step[angles] = (step[angles] + math.pi) % (2 * math.pi) - math.pi
            rates = step / self.dt_s
        else:
            rates = np.array([values[velocity_name(n)] for n in self.positions])
        lags = [self._frames[-k] if len(self._frames) >= k else frame for k in range(1, self.history + 1)]
        self._frames.append(frame)
        del self._frames[: -max(self.history, 1)]
        return np.concatenate([frame, rates] + lags) - self.offset


def reduction_matrices(
    names: tuple[str, ...], params: RodParams, dt_s: float
) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """``(S, P, z_names)``: ``x ~ P z`` to first order about upright for ``z`` the reduced angles and their rates
    (``ex = -L theta``, a frame lagged ``k`` steps at ``position - k dt rate``), ``z = S x``, ``S P = I``."""
    angles = ("phi_rad", "theta_rad", "er_rad") if "er_rad" in names else ("phi_rad", "theta_rad")
    k = len(angles)
    length = params.length_m
    embed = {name: np.eye(k)[i] for i, name in enumerate(angles)}
    embed.setdefault("er_rad", embed["theta_rad"])
    embed["ex_m"] = -length * embed["theta_rad"]
    embed["ey_m"] = np.zeros(k)
    rate_of = {velocity_name(position): position for position in embed}
    p = np.zeros((len(names), 2 * k))
    for i, name in enumerate(names):
        base, _, lag = name.partition("_lag")
        lag_steps = int(lag) if lag else 0
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
    return s, p, angles + tuple(velocity_name(a) for a in angles)


def reduce_learned_model(model_lin: LinearModel, params: RodParams) -> tuple[LinearModel, np.ndarray]:
    """The linearisation projected onto ``z`` (``A_z = S A P``, ``B_z = S B``) and ``S``: the directions the
    data constrain."""
    assert model_lin.dt_s is not None  # a learned model is discrete-time
    s, p, z_names = reduction_matrices(model_lin.state_names, params, model_lin.dt_s)
    reduced = LinearModel(a=s @ model_lin.a @ p, b=s @ model_lin.b, dt_s=model_lin.dt_s, state_names=z_names)
    return reduced, s


def lqr_from_learned_model(model: Any, params: Optional[RodParams] = None) -> LQRController:
    """Discrete LQR designed on the reduced autograd linearisation of the learned model (the true-model
    design's default weights), fed back from the model's state built as in training; ``ValueError`` if the
    linearisation is not stabilisable."""
    params = params if params is not None else RodParams()
    model_lin = linearise_learned_model(model, params)
    design, select = reduce_learned_model(model_lin, params)
    output_map = np.zeros((4, len(design.state_names)))  # y = [theta, phi, theta_dot, phi_dot] from z
    for row, name in enumerate(("theta_rad", "phi_rad", "theta_dot_rad_s", "phi_dot_rad_s")):
        output_map[row, design.state_names.index(name)] = 1.0
    gain = design_lqr(design, output_weight_matrix(output_map), TORQUE_WEIGHT) @ select
    tracker = LearnedStateTracker(model, upright_state_vector(model, params))
    return LQRController(gain, tracker, params.torque_limit_nm, model=model_lin, name="LQR (learned model)")


def learned_model_simulator(model: Any, params: Optional[RodParams] = None):
    """``simulate(controller, tilt_rad, duration_s) -> (theta_rad, torque_nm)`` on the learned model, from the
    straight rod at rest tilted by ``tilt_rad``; the controller sees observations rebuilt from the predicted
    states (``theta = atan2(-ex, ey)`` and backward-difference rates where the model lacks them)."""
    import torch

    params = params if params is not None else RodParams()
    names = tuple(model.layout.names)
    net = model.eval()
    dt_s = float(model.dt_s)

    def to_observation(x: np.ndarray, previous: Optional[dict[str, float]]) -> tuple[Observation, dict[str, float]]:
        v = {name: float(value) for name, value in zip(names, x) if "_lag" not in name}
        theta = math.atan2(-v["ex_m"], v["ey_m"])
        v.setdefault("theta_rad", theta)
        v.setdefault("er_rad", theta)
        for angle in ("theta_rad", "er_rad"):
            rate = angle.replace("_rad", "_dot_rad_s")
            if rate not in v:
                step = 0.0 if previous is None else (v[angle] - previous[angle] + math.pi) % (2 * math.pi) - math.pi
                v[rate] = step / dt_s
        return Observation(*[v[name] for name in OBSERVATION_NAMES]), v

    def simulate(controller: Any, tilt_rad: float, duration_s: float) -> tuple[np.ndarray, np.ndarray]:
        x = _state_vector(names, PRBPlant(params, dt_s=dt_s).reset(*tilt_state(params, tilt_rad)))
        n_steps = int(round(duration_s / dt_s))
        thetas, torques = np.empty(n_steps + 1), np.zeros(n_steps + 1)
        observation, previous = to_observation(x, None)
        thetas[0] = observation.theta_rad
        limit = float(getattr(controller, "torque_limit_nm", params.torque_limit_nm))
        with torch.no_grad():
            for k in range(n_steps):
                torque = min(max(float(controller(observation, None, None, k * dt_s)), -limit), limit)
                torques[k] = torque
                x_t = torch.as_tensor(x, dtype=torch.float32).reshape(1, -1)
                x = net.predict_next(x_t, torch.tensor([torque], dtype=torch.float32)).reshape(-1).double().numpy()
                if not np.all(np.isfinite(x)):
                    thetas[k + 1 :] = np.nan
                    break
                observation, previous = to_observation(x, previous)
                thetas[k + 1] = observation.theta_rad
        return thetas, torques

    return simulate

"""Accuracy of a learned dynamics model on held-out trials: one-step error and open-loop rollout error.

Ground truth is the dataset's observed state (what the model is trained to predict; noise-free unless
the dataset was recorded with sensor noise).  Ensembles are evaluated through their mean prediction.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np
import torch

from softpend.checks import finite, non_negative, positive_int
from softpend.sysid.dataset import TrajectoryDataset
from softpend.sysid.layout import StateLayout
from softpend.sysid.model import DynamicsEnsemble, DynamicsModel
from softpend.sysid.rollout import rollout

__all__ = [
    "evaluate_model",
    "hub_rate_offset_for_tip_error",
    "one_step_errors",
    "perturbed_simulator_errors",
    "RolloutErrors",
    "rollout_errors",
    "rollout_trial",
    "tip_angle_rad",
]


class _MeanOf:
    """Adapter: an ensemble's mean prediction with the single-model signature."""

    def __init__(self, ensemble: DynamicsEnsemble) -> None:
        self.ensemble = ensemble
        self.layout = ensemble.layout

    def predict_next(self, state: torch.Tensor, torque_nm: torch.Tensor, generator: Any = None) -> torch.Tensor:
        return self.ensemble.predict_next(state, torque_nm, member="mean")


def _deterministic(model: Any) -> Any:
    return _MeanOf(model) if isinstance(model, DynamicsEnsemble) else model


def _dtype(model: Any) -> torch.dtype:
    first = model.members[0] if isinstance(model, DynamicsEnsemble) else model
    return first.feature_mean.dtype if isinstance(first, DynamicsModel) else torch.float64


def _wrap(x: np.ndarray) -> np.ndarray:
    return (x + np.pi) % (2 * np.pi) - np.pi


def one_step_errors(
    model: DynamicsModel | DynamicsEnsemble,
    dataset: TrajectoryDataset,
    trials: Optional[np.ndarray] = None,
) -> dict[str, Any]:
    """One-step prediction error over all transitions of the given trials.

    Returns
    -------
    dict
        ``mse``: mean squared error of the predicted next core state (positions and velocities, angle
        errors wrapped) in the report's units [rad^2, m^2, (rad/s)^2, (m/s)^2 averaged], the number to
        set beside the report's ~3e-9; ``mse_trivial``: the same for the "next = current" predictor;
        ``mse_normalised`` / ``mse_normalised_trivial``: both in the network's standardised target
        space (each predicted change divided by its training-set standard deviation: the training
        loss; the trivial predictor scores about 1);
        ``mse_by_variable``: per core variable [report units]; ``one_step_tip_rmse_m``: root-mean-square
        Euclidean tip-position error after one step [m] (when the layout has the tip); ``n_transitions``.
    """
    layout: StateLayout = model.layout
    data = layout.transitions(dataset, trials)
    dtype = _dtype(model)
    with torch.inference_mode():
        states = torch.as_tensor(data.states, dtype=dtype)
        torques = torch.as_tensor(data.torques_nm, dtype=dtype)
        predicted = _deterministic(model).predict_next(states, torques).double().numpy()
    core = layout.core_dim
    mask = layout.angle_mask[:core]
    error = predicted[:, :core] - data.next_states[:, :core]
    error[:, mask] = _wrap(error[:, mask])
    change = data.next_states[:, :core] - data.states[:, :core]
    change[:, mask] = _wrap(change[:, mask])
    # standardised errors in the space the network is trained in (its loss)
    first = (model.members[0] if isinstance(model, DynamicsEnsemble) else model).double()
    with torch.inference_mode():
        s0 = torch.as_tensor(data.states, dtype=torch.float64)
        target = first.target_delta(s0, torch.as_tensor(data.next_states, dtype=torch.float64))
        guess = first.target_delta(s0, torch.as_tensor(predicted, dtype=torch.float64))
        scale = first.delta_std
        normalised = float(torch.mean(((guess - target) / scale) ** 2))
        normalised_trivial = float(torch.mean((target / scale) ** 2))
    first.to(dtype)
    names = layout.names[:core]
    by_variable = {n: float(v) for n, v in zip(names, np.mean(error**2, axis=0))}
    tip = (
        {"one_step_tip_rmse_m": float(np.sqrt(by_variable["ex_m"] + by_variable["ey_m"]))}
        if "ex_m" in by_variable
        else {}
    )
    return {
        "mse": float(np.mean(error**2)),
        "mse_trivial": float(np.mean(change**2)),
        "mse_normalised": normalised,
        "mse_normalised_trivial": normalised_trivial,
        "mse_by_variable": by_variable,
        **tip,
        "n_transitions": int(error.shape[0]),
    }


@dataclass
class RolloutErrors:
    """Open-loop rollout error against the data, as a function of the horizon.

    Attributes
    ----------
    horizon_s : ndarray, shape (H + 1,)
        Time since the rollout start [s] (``0, dt, ..., H dt``).
    tip_rmse_m : ndarray, shape (H + 1,)
        Root-mean-square Euclidean tip-position error ``sqrt(mean((ex - ex*)^2 + (ey - ey*)^2))`` [m].
    phi_rmse_rad : ndarray, shape (H + 1,)
        Root-mean-square wrapped base-angle error [rad].
    hold_tip_rmse_m, hold_phi_rmse_rad : ndarray, shape (H + 1,)
        The same for the trivial prediction "the rod stays where it was at the start" (a yardstick).
    n_rollouts : int
        Number of rollouts averaged (start points over all trials).
    """

    horizon_s: np.ndarray
    tip_rmse_m: np.ndarray
    phi_rmse_rad: np.ndarray
    hold_tip_rmse_m: np.ndarray
    hold_phi_rmse_rad: np.ndarray
    n_rollouts: int

    def at(self, horizon_s: float) -> dict[str, float]:
        """Errors at the sample nearest to ``horizon_s`` [s]."""
        if not 0 <= horizon_s <= self.horizon_s[-1] + 1e-9:
            raise ValueError(f"horizon_s must be in [0, {self.horizon_s[-1]}], got {horizon_s!r}")
        i = int(np.argmin(np.abs(self.horizon_s - horizon_s)))
        return {
            "tip_rmse_m": float(self.tip_rmse_m[i]),
            "phi_rmse_rad": float(self.phi_rmse_rad[i]),
            "hold_tip_rmse_m": float(self.hold_tip_rmse_m[i]),
            "hold_phi_rmse_rad": float(self.hold_phi_rmse_rad[i]),
        }

    def summary(self, horizons_s: tuple[float, ...] = (0.5, 1.0, 2.0)) -> dict[str, float]:
        """Flat dict ``{"tip_rmse_m@1s": ..., ...}`` at the given horizons (those within range)."""
        out: dict[str, float] = {}
        for h in horizons_s:
            if h <= self.horizon_s[-1] + 1e-9:
                for key, value in self.at(h).items():
                    out[f"{key}@{h:g}s"] = value
        return out


def rollout_errors(
    model: DynamicsModel | DynamicsEnsemble,
    dataset: TrajectoryDataset,
    trials: Optional[np.ndarray] = None,
    horizon_s: float = 2.0,
    start_stride: int = 10,
) -> RolloutErrors:
    """Open-loop rollouts from many start points of the given trials under the recorded torques.

    Rollouts start at every ``start_stride``-th state of each trial that leaves ``horizon_s`` of data
    after it; all run in one batched call of :func:`softpend.sysid.rollout`.

    Raises
    ------
    ValueError
        If the trials are shorter than the horizon or the arguments are invalid.
    """
    layout: StateLayout = model.layout
    start_stride = positive_int("start_stride", start_stride)
    steps = int(round(horizon_s / dataset.dt_s))
    if steps < 1:
        raise ValueError(f"horizon_s must be at least one step ({dataset.dt_s} s), got {horizon_s!r}")
    trials = np.arange(dataset.n_trials) if trials is None else np.asarray(trials, dtype=np.int64)
    states = layout.states(dataset)[trials]
    torques = layout.torques(dataset)[trials]
    n_states = states.shape[1]
    if n_states < steps + 1:
        raise ValueError(f"horizon_s={horizon_s} needs {steps + 1} states a trial, the dataset has {n_states}")
    starts = np.arange(0, n_states - steps, start_stride)
    windows = np.stack([states[:, s : s + steps + 1] for s in starts], axis=1).reshape(-1, steps + 1, layout.dim)
    actions = np.stack([torques[:, s : s + steps] for s in starts], axis=1).reshape(-1, steps)
    dtype = _dtype(model)
    with torch.inference_mode():
        predicted = (
            rollout(
                _deterministic(model),
                torch.as_tensor(windows[:, 0], dtype=dtype),
                torch.as_tensor(actions, dtype=dtype),
            )
            .double()
            .numpy()
        )
    i_phi, i_ex, i_ey = (layout.index(n) for n in ("phi_rad", "ex_m", "ey_m"))

    def errors(pred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tip = (pred[..., i_ex] - windows[..., i_ex]) ** 2 + (pred[..., i_ey] - windows[..., i_ey]) ** 2
        phi = _wrap(pred[..., i_phi] - windows[..., i_phi]) ** 2
        return np.sqrt(tip.mean(0)), np.sqrt(phi.mean(0))

    tip, phi = errors(predicted)
    hold_tip, hold_phi = errors(np.repeat(windows[:, :1], steps + 1, axis=1))
    return RolloutErrors(
        horizon_s=np.arange(steps + 1) * dataset.dt_s,
        tip_rmse_m=tip,
        phi_rmse_rad=phi,
        hold_tip_rmse_m=hold_tip,
        hold_phi_rmse_rad=hold_phi,
        n_rollouts=int(windows.shape[0]),
    )


def tip_angle_rad(ex_m: np.ndarray, ey_m: np.ndarray) -> np.ndarray:
    """Tip angle ``theta`` from upright, counter-clockwise positive, from the tip position [rad]."""
    return np.arctan2(-np.asarray(ex_m), np.asarray(ey_m))


def rollout_trial(
    model: DynamicsModel | DynamicsEnsemble,
    dataset: TrajectoryDataset,
    trial: int,
    start_s: float = 0.0,
    duration_s: float = 2.0,
) -> dict[str, np.ndarray]:
    """One open-loop model rollout on one trial, next to the data, for plotting.

    Returns
    -------
    dict
        ``time_s`` (from the trial start) and, for each of ``phi_rad, theta_rad, ex_m, ey_m``, the data
        (``"<name>"``) and the model (``"<name>_model"``); ``theta`` is computed from the tip position
        when the layout does not contain it.
    """
    layout: StateLayout = model.layout
    if not 0 <= trial < dataset.n_trials:
        raise ValueError(f"trial must be in [0, {dataset.n_trials}), got {trial!r}")
    states = layout.states(dataset)[trial]
    torques = layout.torques(dataset)[trial]
    first = int(round(start_s / dataset.dt_s))
    steps = int(round(duration_s / dataset.dt_s))
    if first < 0 or steps < 1 or first + steps >= states.shape[0]:
        raise ValueError(
            f"start_s={start_s}, duration_s={duration_s} do not fit in a trial of {states.shape[0]} states"
        )
    dtype = _dtype(model)
    with torch.inference_mode():
        predicted = (
            rollout(
                _deterministic(model),
                torch.as_tensor(states[first : first + 1], dtype=dtype),
                torch.as_tensor(torques[None, first : first + steps], dtype=dtype),
            )[0]
            .double()
            .numpy()
        )
    truth = states[first : first + steps + 1]
    out = {"time_s": (np.arange(steps + 1) + first + layout.history) * dataset.dt_s}
    for name in ("phi_rad", "theta_rad", "ex_m", "ey_m"):
        if name in layout.names:
            out[name], out[f"{name}_model"] = truth[:, layout.index(name)], predicted[:, layout.index(name)]
        else:  # theta at limited information: from the tip position
            ex, ey = layout.index("ex_m"), layout.index("ey_m")
            out[name] = tip_angle_rad(truth[:, ex], truth[:, ey])
            out[f"{name}_model"] = tip_angle_rad(predicted[:, ex], predicted[:, ey])
    return out


def evaluate_model(
    model: DynamicsModel | DynamicsEnsemble,
    dataset: TrajectoryDataset,
    trials: Optional[np.ndarray] = None,
    horizons_s: tuple[float, ...] = (0.5, 1.0, 2.0),
    start_stride: int = 10,
) -> dict[str, float]:
    """The headline figures on the given trials, as one flat JSON-ready dict: one-step MSE (report units
    and standardised, with the trivial predictor's), open-loop tip-position and base-angle RMSE at
    ``horizons_s`` (model and "hold"), and the tip RMSE as a fraction of the rod length when known."""
    one = one_step_errors(model, dataset, trials)
    out: dict[str, float] = {k: v for k, v in one.items() if k != "mse_by_variable"}
    longest = min(max(horizons_s), (dataset.n_samples - 1 - model.layout.history) * dataset.dt_s)
    errors = rollout_errors(model, dataset, trials, horizon_s=longest, start_stride=start_stride)
    out.update(errors.summary(horizons_s))
    out["n_rollouts"] = errors.n_rollouts
    params = dataset.params
    if params is not None:
        for h in horizons_s:
            key = f"tip_rmse_m@{h:g}s"
            if key in out:
                out[f"tip_rmse_over_length@{h:g}s"] = out[key] / params.length_m
    return out


def perturbed_simulator_errors(
    dataset: TrajectoryDataset,
    trials: Optional[np.ndarray] = None,
    hub_offset_rad: float = 1e-4,
    horizon_s: float = 2.0,
    start_stride: int = 10,
    history: int = 0,
    hub_rate_offset_rad_s: float = 0.0,
    torque_noise_std_nm: float = 0.0,
    seed: int = 0,
) -> RolloutErrors:
    """Yardstick for open-loop errors: the simulator itself, restarted from the recorded joint state with
    the hub angle off by ``hub_offset_rad`` and driven by the recorded torques, against the data.

    Near upright the rod is unstable, so even this "perfect model with a tiny state error" drifts away;
    a learned model cannot be expected to do much better over the same horizon.  Start points are the
    same as :func:`rollout_errors` with ``history`` (use the model's ``layout.history``).  Needs a
    simulated dataset (joint arrays and ``plant_params``).

    ``hub_rate_offset_rad_s`` also starts the hub rate off (with the springs' rates unchanged the whole
    rod turns that much faster: the error a model makes in one step of the tip angle's rate).
    ``torque_noise_std_nm`` adds an independent Gaussian torque error [N m] (seeded by ``seed``) to the
    hub at every step, not clipped by the motor limit: the simulator as a "model" whose only fault is a
    small unmodelled generalised force, i.e. a one-step error that keeps being made, as a learned
    model's is.
    """
    from softpend.plant import make_plant

    if dataset.joint_positions_rad is None or dataset.params is None:
        raise ValueError("perturbed_simulator_errors needs a simulated dataset (joint states and plant_params)")
    assert dataset.joint_velocities_rad_s is not None  # given together with joint_positions_rad
    start_stride = positive_int("start_stride", start_stride)
    finite("hub_offset_rad", hub_offset_rad)
    finite("hub_rate_offset_rad_s", hub_rate_offset_rad_s)
    non_negative("torque_noise_std_nm", torque_noise_std_nm)
    steps = int(round(horizon_s / dataset.dt_s))
    trials = np.arange(dataset.n_trials) if trials is None else np.asarray(trials, dtype=np.int64)
    n_states = dataset.n_samples - history
    if steps < 1 or n_states < steps + 1:
        raise ValueError(f"horizon_s={horizon_s} does not fit in trials of {n_states} states")
    protocol = dataset.metadata.get("protocol", {})
    params = dataset.params
    if torque_noise_std_nm > 0:  # the recorded torques are within the limit already; the error is not clipped
        params = dataclasses.replace(params, torque_limit_nm=params.torque_limit_nm + 100 * torque_noise_std_nm)
    plant = make_plant(
        dataset.metadata.get("plant") or "prb",
        params=params,
        dt_s=dataset.dt_s,
        substeps=int(protocol.get("substeps", 2)),
    )
    rng = np.random.default_rng(seed)
    names = dataset.position_names
    i_phi, i_ex, i_ey = (names.index(n) for n in ("phi_rad", "ex_m", "ey_m"))
    tip_sq = np.zeros(steps + 1)
    phi_sq = np.zeros(steps + 1)
    hold_tip_sq = np.zeros(steps + 1)
    hold_phi_sq = np.zeros(steps + 1)
    count = 0
    for trial in trials:
        for start in range(history, history + n_states - steps, start_stride):
            q = dataset.joint_positions_rad[trial, start].copy()
            q[0] += hub_offset_rad
            qd = dataset.joint_velocities_rad_s[trial, start].copy()
            qd[0] += hub_rate_offset_rad_s
            plant.reset(q, qd)
            path = [plant.observe()]
            for k in range(steps):
                noise = torque_noise_std_nm * rng.standard_normal() if torque_noise_std_nm > 0 else 0.0
                path.append(plant.step(dataset.torques_nm[trial, start + k] + noise))
            truth = dataset.positions[trial, start : start + steps + 1]
            ex = np.array([o.ex_m for o in path])
            ey = np.array([o.ey_m for o in path])
            phi = np.array([o.phi_rad for o in path])
            tip_sq += (ex - truth[:, i_ex]) ** 2 + (ey - truth[:, i_ey]) ** 2
            phi_sq += _wrap(phi - truth[:, i_phi]) ** 2
            hold_tip_sq += (truth[0, i_ex] - truth[:, i_ex]) ** 2 + (truth[0, i_ey] - truth[:, i_ey]) ** 2
            hold_phi_sq += _wrap(truth[0, i_phi] - truth[:, i_phi]) ** 2
            count += 1
    return RolloutErrors(
        horizon_s=np.arange(steps + 1) * dataset.dt_s,
        tip_rmse_m=np.sqrt(tip_sq / count),
        phi_rmse_rad=np.sqrt(phi_sq / count),
        hold_tip_rmse_m=np.sqrt(hold_tip_sq / count),
        hold_phi_rmse_rad=np.sqrt(hold_phi_sq / count),
        n_rollouts=count,
    )


def hub_rate_offset_for_tip_error(dataset: TrajectoryDataset, tip_error_m: float, history: int = 0) -> float:
    """The hub-rate offset [rad/s] that makes :func:`perturbed_simulator_errors` miss the recorded tip by
    ``tip_error_m`` (RMS over every start point of the trials) after its first step.

    Started with the hub rate off and the springs' rates unchanged, the rod turns rigidly a little faster,
    so the first-step tip error is proportional to the offset (about ``dt * L`` per rad/s); it is
    measured once with a 1e-2 rad/s offset and scaled.  With a model's one-step tip RMSE this gives a
    perfect simulator that makes the model's one-step error once, at the start of each rollout.

    Raises
    ------
    ValueError
        If ``tip_error_m`` is not positive, or the dataset is not simulated.
    """
    if not (np.isfinite(tip_error_m) and tip_error_m > 0):
        raise ValueError(f"tip_error_m must be positive, got {tip_error_m!r}")
    reference_rad_s = 1e-2
    first_step = perturbed_simulator_errors(
        dataset,
        hub_offset_rad=0.0,
        hub_rate_offset_rad_s=reference_rad_s,
        horizon_s=dataset.dt_s,
        start_stride=1,
        history=history,
    )
    return reference_rad_s * tip_error_m / float(first_step.tip_rmse_m[1])

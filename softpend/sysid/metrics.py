"""Accuracy of a learned dynamics model on held-out trials against the observed states: one-step error and
open-loop rollout error (ensembles through their mean prediction)."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np
import torch

from softpend.checks import finite, non_negative, positive, positive_int
from softpend.plant import make_plant, wrap_angle_rad
from softpend.plant.base import PlantBase
from softpend.sysid.dataset import TrajectoryDataset
from softpend.sysid.greybox import dataset_substeps, simulate_windows
from softpend.sysid.layout import StateLayout
from softpend.sysid.model import DynamicsEnsemble, DynamicsModel


def open_loop(model: Any, x0: np.ndarray, torques_nm: np.ndarray) -> np.ndarray:
    """Open-loop predictions ``(B, T + 1, d)`` of a model (ensembles: their mean) under torques ``(B, T)``."""
    predict, dtype = model.predict_next, model.feature_mean.dtype if isinstance(model, DynamicsModel) else torch.float64
    if isinstance(model, DynamicsEnsemble):
        predict, dtype = functools.partial(model.predict_next, member="mean"), model.members[0].feature_mean.dtype
    with torch.inference_mode():
        x = [torch.as_tensor(x0, dtype=dtype)]
        for torque in torch.as_tensor(torques_nm, dtype=dtype).T:
            x.append(predict(x[-1], torque))
    return torch.stack(x, dim=1).double().numpy()


def one_step_errors(
    model: DynamicsModel | DynamicsEnsemble,
    dataset: TrajectoryDataset,
    trials: Optional[np.ndarray] = None,
) -> dict[str, Any]:
    """One-step mean squared error of the next core state (angles wrapped) over the trials' transitions, in the
    report's units and standardised, beside "next = current", per variable, and the tip RMSE [m] if observed."""
    layout: StateLayout = model.layout
    data = layout.transitions(dataset, trials)
    predicted = open_loop(model, data.states, data.torques_nm[:, None])[:, 1]
    core, mask = layout.core_dim, layout.angle_mask[: layout.core_dim]
    error, change = predicted[:, :core] - data.next_states[:, :core], data.next_states[:, :core] - data.states[:, :core]
    for x in (error, change):
        x[:, mask] = wrap_angle_rad(x[:, mask])
    first = model.members[0] if isinstance(model, DynamicsEnsemble) else model
    dtype = first.feature_mean.dtype
    first.double()
    with torch.inference_mode():
        s0, s1, guess = (torch.as_tensor(x, dtype=torch.float64) for x in (data.states, data.next_states, predicted))
        target, guess = first.target_delta(s0, s1), first.target_delta(s0, guess)
        normalised = float(torch.mean(((guess - target) / first.delta_std) ** 2))
        normalised_trivial = float(torch.mean((target / first.delta_std) ** 2))
    first.to(dtype)
    by_variable = {n: float(v) for n, v in zip(layout.names[:core], np.mean(error**2, axis=0))}
    out: dict[str, Any] = {"mse": float(np.mean(error**2)), "mse_trivial": float(np.mean(change**2))}
    out |= {"mse_normalised": normalised, "mse_normalised_trivial": normalised_trivial, "mse_by_variable": by_variable}
    tip = float(np.sqrt(by_variable["ex_m"] + by_variable["ey_m"]))
    return out | {"one_step_tip_rmse_m": tip, "n_transitions": int(error.shape[0])}


@dataclass
class RolloutErrors:
    """Open-loop RMS tip-position [m] and hub-angle [rad] errors against the data at horizons ``0, dt, ..., H dt``,
    and the same for "the rod stays where it was" (``hold_``), over ``n_rollouts`` start points."""

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
        names = ("tip_rmse_m", "phi_rmse_rad", "hold_tip_rmse_m", "hold_phi_rmse_rad")
        return {name: float(getattr(self, name)[i]) for name in names}

    def summary(self, horizons_s: tuple[float, ...] = (0.5, 1.0, 2.0)) -> dict[str, float]:
        """Flat dict ``{"tip_rmse_m@1s": ..., ...}`` at the given horizons (those within range)."""
        inside = [h for h in horizons_s if h <= self.horizon_s[-1] + 1e-9]
        return {f"{key}@{h:g}s": value for h in inside for key, value in self.at(h).items()}


def _rms_errors(predicted: np.ndarray, truth: np.ndarray, steps: int, dt_s: float) -> RolloutErrors:
    """:class:`RolloutErrors` of predictions ``(B, H + 1, 3)`` of ``(phi, ex, ey)`` against the truth."""

    def errors(pred: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        tip = (pred[..., 1] - truth[..., 1]) ** 2 + (pred[..., 2] - truth[..., 2]) ** 2
        phi = np.asarray(wrap_angle_rad(pred[..., 0] - truth[..., 0])) ** 2
        return np.sqrt(tip.mean(0)), np.sqrt(phi.mean(0))

    hold = np.repeat(truth[:, :1], steps + 1, axis=1)
    return RolloutErrors(np.arange(steps + 1) * dt_s, *errors(predicted), *errors(hold), int(truth.shape[0]))


def network_rollouts(
    model: Any, dataset: TrajectoryDataset, starts: np.ndarray, steps: int
) -> tuple[np.ndarray, np.ndarray]:
    """Observed states ``(B, steps + 1, d)`` of a model's layout from each start ``(trial, sample)`` on, and the
    model's open-loop predictions of them (ensembles: their mean) under the recorded torques."""
    layout = model.layout
    if np.any(starts[:, 1] < layout.history):
        raise ValueError(f"rollout starts must be at sample {layout.history} or later (the model's history)")
    i = starts[:, 1:2] - layout.history + np.arange(steps + 1)[None, :]
    truth = layout.states(dataset)[starts[:, :1], i]
    return truth, open_loop(model, truth[:, 0], layout.torques(dataset)[starts[:, :1], i[:, :-1]])


def trial_curves(
    time_s: np.ndarray, data: dict[str, np.ndarray], model: dict[str, np.ndarray]
) -> dict[str, np.ndarray]:
    """``time_s`` and, for each of ``phi_rad, theta_rad, ex_m, ey_m``, the data (``name``) and the model
    (``name_model``); theta from the tip position where not given."""
    out = {"time_s": time_s}
    for suffix, values in (("", data), ("_model", model)):
        theta = values.get("theta_rad", np.arctan2(-values["ex_m"], values["ey_m"]))
        out |= {f"{n}{suffix}": values[n] for n in ("phi_rad", "ex_m", "ey_m")} | {f"theta_rad{suffix}": theta}
    return out


def rollout_starts(
    dataset: TrajectoryDataset,
    steps: int,
    stride: int = 10,
    first: int = 0,
    max_tilt_rad: Optional[float] = None,
    trials: Optional[np.ndarray] = None,
) -> np.ndarray:
    """Rows ``(trial, sample)`` of every ``stride``-th sample from ``first`` that leaves ``steps`` samples after it,
    in ``trials`` (default: all), optionally only those with ``|theta| <= max_tilt_rad``."""
    steps, stride = positive_int("steps", steps), positive_int("stride", stride)
    trials = np.arange(dataset.n_trials) if trials is None else np.asarray(trials, dtype=np.int64)
    samples = np.arange(int(first), dataset.n_samples - steps, stride)
    grid = np.array([(t, s) for t in trials for s in samples], dtype=np.int64).reshape(-1, 2)
    if max_tilt_rad is not None and grid.size:
        theta = np.arctan2(-dataset.column("ex_m"), dataset.column("ey_m"))
        grid = grid[np.abs(theta[grid[:, 0], grid[:, 1]]) <= positive("max_tilt_rad", max_tilt_rad)]
    if grid.shape[0] == 0:
        tilt = "" if max_tilt_rad is None else f" with |theta| <= {max_tilt_rad} rad at its start"
        raise ValueError(f"no rollout of {steps} steps fits the dataset's trials of {dataset.n_samples} samples{tilt}")
    return grid


def recorded_states(dataset: TrajectoryDataset, starts: np.ndarray) -> np.ndarray:
    """The recorded joint states ``(B, 2 J)`` at rows ``(trial, sample)`` of a simulated dataset."""
    if dataset.joint_positions_rad is None or dataset.joint_velocities_rad_s is None:
        raise ValueError("dataset has no recorded joint states (needs a simulated dataset)")
    q = dataset.joint_positions_rad[starts[:, 0], starts[:, 1]]
    return np.concatenate([q, dataset.joint_velocities_rad_s[starts[:, 0], starts[:, 1]]], axis=1)


def _steps(horizon_s: float, dataset: TrajectoryDataset, history: int) -> int:
    steps, n_states = int(round(horizon_s / dataset.dt_s)), dataset.n_samples - history
    if steps < 1 or n_states < steps + 1:
        raise ValueError(f"horizon_s={horizon_s} must be at least one step and fit in trials of {n_states} states")
    return steps


def rollout_errors(
    model: DynamicsModel | DynamicsEnsemble,
    dataset: TrajectoryDataset,
    trials: Optional[np.ndarray] = None,
    horizon_s: float = 2.0,
    start_stride: int = 10,
) -> RolloutErrors:
    """Open-loop rollouts from every ``start_stride``-th state that leaves ``horizon_s`` in its trial."""
    layout: StateLayout = model.layout
    steps = _steps(horizon_s, dataset, layout.history)
    starts = rollout_starts(dataset, steps, start_stride, layout.history, trials=trials)
    windows, predicted = network_rollouts(model, dataset, starts, steps)
    columns = [layout.index(n) for n in ("phi_rad", "ex_m", "ey_m")]
    return _rms_errors(predicted[..., columns], windows[..., columns], steps, dataset.dt_s)


def rollout_trial(
    model: DynamicsModel | DynamicsEnsemble,
    dataset: TrajectoryDataset,
    trial: int,
    start_s: float = 0.0,
    duration_s: float = 2.0,
) -> dict[str, np.ndarray]:
    """One open-loop model rollout on one trial next to the data, for plotting (:func:`trial_curves`)."""
    layout: StateLayout = model.layout
    if not 0 <= trial < dataset.n_trials:
        raise ValueError(f"trial must be in [0, {dataset.n_trials}), got {trial!r}")
    first = int(round(start_s / dataset.dt_s))
    steps = int(round(duration_s / dataset.dt_s))
    n_states = dataset.n_samples - layout.history
    if first < 0 or steps < 1 or first + steps >= n_states:
        raise ValueError(f"start_s={start_s}, duration_s={duration_s} do not fit in a trial of {n_states} states")
    truth, predicted = network_rollouts(model, dataset, np.array([[trial, first + layout.history]]), steps)
    columns = [{n: x[0, :, layout.index(n)] for n in layout.position_names} for x in (truth, predicted)]
    return trial_curves((np.arange(steps + 1) + first + layout.history) * dataset.dt_s, *columns)


def evaluate_model(
    model: DynamicsModel | DynamicsEnsemble,
    dataset: TrajectoryDataset,
    trials: Optional[np.ndarray] = None,
    horizons_s: tuple[float, ...] = (0.5, 1.0, 2.0),
    start_stride: int = 10,
) -> dict[str, float]:
    """The headline figures on the given trials as one flat JSON-ready dict: one-step errors, open-loop errors at
    ``horizons_s``, and the tip RMSE as a fraction of the rod length when known."""
    one = one_step_errors(model, dataset, trials)
    out: dict[str, float] = {k: v for k, v in one.items() if k != "mse_by_variable"}
    longest = min(max(horizons_s), (dataset.n_samples - 1 - model.layout.history) * dataset.dt_s)
    errors = rollout_errors(model, dataset, trials, horizon_s=longest, start_stride=start_stride)
    out |= errors.summary(horizons_s) | {"n_rollouts": errors.n_rollouts}
    if dataset.params is not None:
        tips = {k: v for k, v in out.items() if k.startswith("tip_rmse_m@")}
        out |= {k.replace("_m@", "_over_length@"): v / dataset.params.length_m for k, v in tips.items()}
    return out


def simulator_rollouts(
    plant: PlantBase,
    dataset: TrajectoryDataset,
    starts: np.ndarray,
    steps: int,
    initial_states: Optional[np.ndarray] = None,
    hub_offset_rad: float = 0.0,
    hub_rate_offset_rad_s: float = 0.0,
    torque_noise_nm: float | np.ndarray = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Open-loop rollouts ``(B, steps + 1, 3)`` of ``phi, ex, ey`` of ``plant`` from the recorded joint states (or
    ``initial_states``) with the hub angle and rate moved by the offsets, under the recorded torques plus
    ``torque_noise_nm``; and their samples ``(B, steps + 1)``."""
    states = recorded_states(dataset, starts) if initial_states is None else np.array(initial_states, dtype=float)
    states = states.reshape(starts.shape[0], -1)
    n_q = plant.n_coordinates
    if states.shape[1] != 2 * n_q:
        raise ValueError(f"the joint states have {states.shape[1] // 2} coordinates, not {n_q}")
    states[:, [0, n_q]] += (hub_offset_rad, hub_rate_offset_rad_s)
    index = starts[:, 1:2] + np.arange(positive_int("steps", steps) + 1)
    torques = dataset.torques_nm[starts[:, :1], index[:, :-1]] + torque_noise_nm
    return simulate_windows(plant, states, torques, has_er=False), index


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
    """Yardstick: the simulator restarted from the recorded joint states (simulated datasets) with the hub angle
    and rate off and seeded Gaussian torque noise, at the start points of :func:`rollout_errors` with ``history``."""
    if dataset.params is None:
        raise ValueError("perturbed_simulator_errors needs a simulated dataset (joint states and plant_params)")
    finite("hub_offset_rad", hub_offset_rad)
    finite("hub_rate_offset_rad_s", hub_rate_offset_rad_s)
    non_negative("torque_noise_std_nm", torque_noise_std_nm)
    steps = _steps(horizon_s, dataset, history)
    starts = rollout_starts(dataset, steps, start_stride, history, trials=trials)
    params = dataset.params
    if torque_noise_std_nm > 0:  # the recorded torques are within the limit already; the error is not clipped
        params = params.replace(torque_limit_nm=params.torque_limit_nm + 100 * torque_noise_std_nm)
    plant_name = dataset.metadata.get("plant") or "prb"
    plant = make_plant(plant_name, params=params, dt_s=dataset.dt_s, substeps=dataset_substeps(dataset))
    noise = torque_noise_std_nm * np.random.default_rng(seed).standard_normal((len(starts), steps))
    predicted, index = simulator_rollouts(
        plant,
        dataset,
        starts,
        steps,
        hub_offset_rad=hub_offset_rad,
        hub_rate_offset_rad_s=hub_rate_offset_rad_s,
        torque_noise_nm=noise,
    )
    columns = [dataset.position_names.index(n) for n in ("phi_rad", "ex_m", "ey_m")]
    return _rms_errors(predicted, dataset.positions[starts[:, :1], index][..., columns], steps, dataset.dt_s)


def hub_rate_offset_for_tip_error(dataset: TrajectoryDataset, tip_error_m: float, history: int = 0) -> float:
    """The hub-rate offset [rad/s] that makes :func:`perturbed_simulator_errors` miss the recorded tip by
    ``tip_error_m`` (RMS) after its first step (the error is proportional to the offset)."""
    tip_error_m = positive("tip_error_m", tip_error_m)
    settings: dict[str, Any] = dict(hub_offset_rad=0.0, hub_rate_offset_rad_s=1e-2, horizon_s=dataset.dt_s)
    first_step = perturbed_simulator_errors(dataset, start_stride=1, history=history, **settings)
    return 1e-2 * tip_error_m / float(first_step.tip_rmse_m[1])

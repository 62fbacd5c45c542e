"""Model quality as an unstable plant allows: valid prediction time (median horizon within 5 % of the rod length,
in seconds and Lyapunov times), the tip error at a fixed horizon, and the grey-box model's one-step error."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from softpend.checks import non_negative, positive, positive_int
from softpend.plant import RodParams
from softpend.sysid.dataset import TrajectoryDataset
from softpend.sysid.greybox import free_plant, wrap_diff
from softpend.sysid.metrics import network_rollouts, recorded_states, rollout_starts, simulator_rollouts, trial_curves

#: Tip-error threshold of the valid prediction time, as a fraction of the rod length.
VALID_TIP_FRACTION = 0.05


@dataclass(frozen=True)
class ValidPrediction:
    """Valid prediction times [s] (``censored``: never left the threshold), their median [s] and in Lyapunov times."""

    times_s: np.ndarray
    censored: np.ndarray
    median_s: float
    median_lyapunov: float


def valid_prediction(
    tip_error_m: np.ndarray, dt_s: float, length_m: float, lyapunov_rate_per_s: Optional[float] = None
) -> ValidPrediction:
    """Valid prediction times of rollouts from their tip errors ``(B, H + 1)`` [m]: ``(k - 1) dt`` for a rollout
    first above :data:`VALID_TIP_FRACTION` of ``length_m`` at sample ``k``, ``H dt`` (censored) if never."""
    error = np.asarray(tip_error_m, dtype=float)
    if error.ndim != 2 or error.shape[0] < 1 or error.shape[1] < 2:
        raise ValueError(f"tip_error_m must have shape (B >= 1, H + 1 >= 2), got {error.shape}")
    if not np.all(np.isfinite(error)) or error.min() < 0:
        raise ValueError("tip_error_m must be finite and non-negative")
    threshold = VALID_TIP_FRACTION * positive("length_m", length_m)
    above = error > threshold
    censored: np.ndarray = ~above.any(axis=1)  # type: ignore[assignment]  # numpy's stubs allow a scalar for an unknown ndim
    first = np.where(censored, error.shape[1], np.argmax(above, axis=1))
    times = np.maximum(first - 1, 0) * positive("dt_s", dt_s)
    median = float(np.median(times))
    rate = math.nan if lyapunov_rate_per_s is None else positive("lyapunov_rate_per_s", lyapunov_rate_per_s)
    return ValidPrediction(times, censored, median, float(median * rate))


def tip_rmse_at_s(tip_error_m: np.ndarray, dt_s: float, horizon_s: float) -> float:
    """Root-mean-square over rollouts of the tip error at the sample nearest ``horizon_s`` [m]."""
    error = np.asarray(tip_error_m, dtype=float)
    k = int(round(non_negative("horizon_s", horizon_s) / positive("dt_s", dt_s)))
    if error.ndim != 2 or not 0 <= k < error.shape[1]:
        raise ValueError(f"horizon_s={horizon_s} is outside rollouts of {error.shape[-1] - 1} steps")
    return float(np.sqrt(np.mean(error[:, k] ** 2)))


def prb_rollout_tip_errors(
    params: RodParams,
    dataset: TrajectoryDataset,
    starts: np.ndarray,
    steps: int,
    hub_offset_rad: float = 0.0,
    initial_states: Optional[np.ndarray] = None,
) -> np.ndarray:
    """Tip errors ``(B, steps + 1)`` [m] against the data of open-loop PRB rollouts with ``params`` from the recorded
    joint states (or ``initial_states``), the hub angle moved by ``hub_offset_rad``, under the recorded torques."""
    plant = free_plant(params, dataset)
    sim, index = simulator_rollouts(plant, dataset, starts, steps, initial_states, hub_offset_rad)
    rows = starts[:, :1]
    return np.hypot(
        sim[..., 1] - dataset.column("ex_m")[rows, index], sim[..., 2] - dataset.column("ey_m")[rows, index]
    )


def prb_rollout_trial(
    params: RodParams,
    dataset: TrajectoryDataset,
    trial: int,
    start_sample: int,
    steps: int,
    initial_state: Optional[np.ndarray] = None,
) -> dict[str, np.ndarray]:
    """One open-loop PRB rollout from the recorded joint state (or ``initial_state``) in the format of
    :func:`softpend.sysid.rollout_trial`."""
    if not 0 <= trial < dataset.n_trials or not 0 <= start_sample < dataset.n_samples - steps:
        raise ValueError(f"trial {trial}, start_sample {start_sample} and {steps} steps do not fit the dataset")
    plant, starts = free_plant(params, dataset), np.array([[trial, start_sample]])
    sim, index = simulator_rollouts(plant, dataset, starts, steps, initial_state)
    names = ("phi_rad", "ex_m", "ey_m")
    data = {name: dataset.column(name)[trial, index[0]] for name in names}
    return trial_curves(index[0] * dataset.dt_s, data, {name: sim[0, :, k] for k, name in enumerate(names)})


def network_rollout_tip_errors(model: Any, dataset: TrajectoryDataset, starts: np.ndarray, steps: int) -> np.ndarray:
    """Tip errors ``(B, steps + 1)`` [m] of a learned model's open-loop rollouts (:func:`network_rollouts`)."""
    truth, predicted = network_rollouts(model, dataset, starts, positive_int("steps", steps))
    i_ex, i_ey = model.layout.index("ex_m"), model.layout.index("ey_m")
    return np.hypot(predicted[..., i_ex] - truth[..., i_ex], predicted[..., i_ey] - truth[..., i_ey])


def prb_one_step_errors(
    params: RodParams,
    dataset: TrajectoryDataset,
    trials: Optional[np.ndarray] = None,
) -> dict[str, float]:
    """One-step error of a PRB model from the recorded joint state at every sample of the trials, in the units of
    :func:`softpend.sysid.one_step_errors` at full information (velocities as backward differences)."""
    starts = rollout_starts(dataset, 1, stride=1, trials=trials)
    plant, names = free_plant(params, dataset), dataset.position_names
    predicted = np.empty((starts.shape[0], len(names)))
    for row, ((t, s), state) in enumerate(zip(starts, recorded_states(dataset, starts))):
        plant.reset(state[: plant.n_coordinates], state[plant.n_coordinates :])
        o = plant.step(dataset.torques_nm[t, s])
        predicted[row] = [getattr(o, n) for n in names]
    angle = np.array([n in ("phi_rad", "theta_rad", "er_rad") for n in names])
    position_error = predicted - dataset.positions[starts[:, 0], starts[:, 1] + 1]
    position_error[:, angle] = wrap_diff(position_error[:, angle], 0.0)
    error = np.concatenate([position_error, position_error / dataset.dt_s], axis=1)
    tip_x, tip_y = position_error[:, names.index("ex_m")], position_error[:, names.index("ey_m")]
    tip = float(np.sqrt(np.mean(tip_x**2 + tip_y**2)))
    return {"mse": float(np.mean(error**2)), "one_step_tip_rmse_m": tip, "n_transitions": int(starts.shape[0])}

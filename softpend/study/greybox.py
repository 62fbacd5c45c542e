"""Grey-box identification in the study: the initial guess, model quality, closed-loop usefulness."""

from __future__ import annotations

import math
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from softpend.control.linearise import linearise_exudyn
from softpend.control.lqr import LQRController
from softpend.control.swingup import EnergySwingUpController
from softpend.evaluation import TEST_EPISODE_S, evaluate_controller
from softpend.plant import RodParams
from softpend.study.classical import run_from_tilt
from softpend.study.presets import REPORT_SEEDS
from softpend.sysid.babble import BabbleProtocol
from softpend.sysid.dataset import TrajectoryDataset
from softpend.sysid.greybox import estimate_joint_states
from softpend.sysid.metrics import one_step_errors
from softpend.sysid.quality import (
    network_rollout_tip_errors,
    prb_one_step_errors,
    prb_rollout_tip_errors,
    rollout_starts,
    tip_rmse_at_s,
    valid_prediction,
)
from softpend.task import Task

#: Initial guess of the study's identifications: each estimated field times this factor.
GUESS_FACTORS: dict[str, float] = {
    "hub_inertia_kgm2": 1.5,
    "hub_friction_nms_per_rad": 0.6,
    "youngs_modulus_pa": 1.3,
    "joint_damping_nms_per_rad": 2.0,
    "tip_mass_kg": 0.7,
}
#: Held-out babbling around the hanging equilibrium: no feedback, random torque.
HANGING_PROTOCOL = BabbleProtocol(
    n_trials=6,
    trial_length_s=3.0,
    start="hanging",
    start_angle_std_rad=0.3,
    start_rate_std_rad_s=1.0,
    feedback_trial_fraction=0.0,
)
#: Yardstick: the simulator restarted with the hub angle this far off [rad].
YARDSTICK_OFFSET_RAD = 1e-4
#: Its row label in :func:`model_quality`.
YARDSTICK_LABEL = f"simulator started {YARDSTICK_OFFSET_RAD:g} rad off"


def perturbed_guess(truth: RodParams, factors: Mapping[str, float] = GUESS_FACTORS) -> RodParams:
    """``truth`` with each field of ``factors`` multiplied by its factor."""
    return truth.replace(**{name: getattr(truth, name) * factor for name, factor in factors.items()})


def model_quality(
    identified: RodParams,
    upright: TrajectoryDataset,
    hanging: Optional[TrajectoryDataset] = None,
    networks: Optional[Mapping[str, Any]] = None,
    horizon_s: float = 2.0,
    start_state: str = "recorded",
) -> dict[str, Any]:
    """The model-quality table (valid prediction time, hanging tip error at 1 s, one-step error) of the grey-box
    model, the yardstick and ``networks`` on held-out data; ``start_state``: ``"recorded"`` joint states (simulated
    PRB data) or ``"estimated"`` from the preceding 0.1 s of observations."""
    stride, lookback_s, hanging_horizon_s = 10, 0.1, 1.0
    truth = upright.params
    if truth is None:
        raise ValueError("upright must be a simulated dataset with plant_params")
    if start_state not in ("recorded", "estimated"):
        raise ValueError(f"start_state must be 'recorded' or 'estimated', got {start_state!r}")
    networks = dict(networks or {})
    recorded_prb = all(
        d is None or (d.metadata.get("plant") == "prb" and d.joint_positions_rad is not None)
        for d in (upright, hanging)
    )
    if start_state == "recorded" and not recorded_prb:
        raise ValueError("start_state='recorded' needs simulated PRB data; use start_state='estimated'")
    lookback = int(round(lookback_s / upright.dt_s)) + 1 if start_state == "estimated" else 0

    def all_errors(data: TrajectoryDataset, starts: np.ndarray, n_steps: int) -> dict[str, np.ndarray]:
        states = None if start_state == "recorded" else estimate_joint_states(identified, data, starts, lookback_s)
        errors = {"grey-box model": prb_rollout_tip_errors(identified, data, starts, n_steps, initial_states=states)}
        if recorded_prb:
            errors[YARDSTICK_LABEL] = prb_rollout_tip_errors(
                truth, data, starts, n_steps, hub_offset_rad=YARDSTICK_OFFSET_RAD
            )
        for label, model in networks.items():
            errors[label] = network_rollout_tip_errors(model, data, starts, n_steps)
        return errors

    # the growth rate at upright [1/s]
    lam = float(np.max(linearise_exudyn(truth).state_space().eigenvalues().real))
    length, dt = truth.length_m, upright.dt_s
    steps = int(round(horizon_s / dt))
    first = max([lookback] + [m.layout.history for m in networks.values()])
    starts = rollout_starts(upright, steps, stride=stride, first=first, max_tilt_rad=0.3)
    errors = all_errors(upright, starts, steps)
    rows: dict[str, dict[str, float]] = {}
    for label, error in errors.items():
        vp = valid_prediction(error, dt, length, lyapunov_rate_per_s=lam)
        figures = (vp.median_s, vp.median_lyapunov, float(np.mean(vp.censored)))
        rows[label] = dict(zip(("valid_prediction_s", "valid_prediction_lyapunov", "censored_fraction"), figures))
    if hanging is not None:
        h_steps = int(round(hanging_horizon_s / hanging.dt_s))
        h_starts = rollout_starts(hanging, h_steps, stride=stride, first=first)
        for label, error in all_errors(hanging, h_starts, h_steps).items():
            rmse = tip_rmse_at_s(error, hanging.dt_s, hanging_horizon_s)
            rows[label]["hanging_tip_rmse_pct_length"] = 100 * rmse / length
    one_step = {label: one_step_errors(model, upright) for label, model in networks.items()}
    if recorded_prb:
        one_step["grey-box model"] = prb_one_step_errors(identified, upright)
    for label, one in one_step.items():
        rows[label] |= {"one_step_mse": one["mse"], "one_step_tip_rmse_m": one.get("one_step_tip_rmse_m", math.nan)}
    curves = {label: np.sqrt(np.mean(error**2, axis=0)) for label, error in errors.items()}
    quality = {"lyapunov_rate_per_s": lam, "length_m": length, "rows": rows, "curves": curves}
    return quality | {"horizon_s": np.arange(steps + 1) * dt, "n_rollouts": int(starts.shape[0])}


def closed_loop_usefulness(
    identified: Mapping[str, RodParams], task: Task = Task(), seeds: Optional[Sequence[int]] = None
) -> list[dict[str, Any]]:
    """LQR (from 0.2 rad) and energy swing-up + LQR (from hanging) designed on each of ``identified`` and on
    ``task.rod``, on the true plant from ``seeds``: one row per design and start."""
    joint = task.plant == "prb"  # other plants (the beam): the observation-feedback versions of both designs
    seeds = [int(s) for s in (seeds if seeds is not None else REPORT_SEEDS[:10])]
    designs = {"true parameters": task.rod, **dict(identified)}
    rows: list[dict[str, Any]] = []
    for label, params in designs.items():
        params = params.replace(torque_limit_nm=task.rod.torque_limit_nm)
        lqr_controller = LQRController.from_params(params, state="joint" if joint else "observation")
        lqr = run_from_tilt(lqr_controller, task, 0.2, seeds, 5.0, task.torque_limit_nm, "LQR")
        swing_controller = (EnergySwingUpController if joint else EnergySwingUpController.for_observations)(params)
        name, hanging = "energy swing-up + LQR", task.replace(start="hanging")
        swing = evaluate_controller(swing_controller, hanging, seeds=seeds, duration_s=TEST_EPISODE_S, name=name)
        for s, start in ((lqr, "tilt 0.2 rad"), (swing, "hanging")):
            row = {"designed_on": label, "controller": s.name, "start": start, "success_rate": s.success_rate}
            row |= {"successes": s.successes, "episodes": len(s.results)}
            rows.append(row | {"upright_std_rad": s.median("upright_std_rad")})
    return rows

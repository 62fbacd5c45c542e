"""Grey-box identification in the study: model quality against the networks, and closed-loop usefulness.

* :func:`upright_growth_rate_per_s`: ``lambda``, the largest real part of the eigenvalues of the linearisation
  at upright (:func:`softpend.control.linearise.linearise_exudyn`); ``1 / lambda`` is the Lyapunov time.
* :func:`perturbed_guess`: the initial guess of the identifications of the study, every estimated field off
  the truth by :data:`GUESS_FACTORS`.
* :func:`model_quality`: the model-quality table of :mod:`softpend.sysid.quality` for the grey-box model, the
  "simulator started 1e-4 rad off" yardstick and any learned networks, on held-out upright and hanging data.
* :func:`closed_loop_usefulness`: LQR (from a tilt) and energy swing-up + LQR (from hanging) designed on
  identified parameters and on the true ones, run on the true plant from the same fresh starts.
"""

from __future__ import annotations

from typing import Any, Mapping, Optional, Sequence

import numpy as np

from softpend.evaluation import TEST_EPISODE_S
from softpend.plant import RodParams
from softpend.sysid.babble import BabbleProtocol
from softpend.sysid.dataset import TrajectoryDataset
from softpend.sysid.greybox import estimate_joint_states
from softpend.sysid.quality import (
    network_rollout_tip_errors,
    prb_one_step_errors,
    prb_rollout_tip_errors,
    rollout_starts,
    tip_rmse_at_s,
    valid_prediction,
)
from softpend.task import Task

__all__ = [
    "GUESS_FACTORS",
    "HANGING_PROTOCOL",
    "closed_loop_usefulness",
    "model_quality",
    "perturbed_guess",
    "upright_growth_rate_per_s",
]

#: Initial guess of the study's identifications: each estimated field times this factor of the truth.
GUESS_FACTORS: dict[str, float] = {
    "hub_inertia_kgm2": 1.5,
    "hub_friction_nms_per_rad": 0.6,
    "youngs_modulus_pa": 1.3,
    "joint_damping_nms_per_rad": 2.0,
    "tip_mass_kg": 0.7,
}
#: Held-out babbling around the hanging equilibrium (the stable regime): no feedback, random torque.
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


def upright_growth_rate_per_s(params: RodParams) -> float:
    """``lambda`` [1/s]: the largest real part of the eigenvalues of the linearisation at upright."""
    from softpend.control.linearise import linearise_exudyn

    return float(np.max(linearise_exudyn(params).state_space().eigenvalues().real))


def perturbed_guess(truth: RodParams, factors: Mapping[str, float] = GUESS_FACTORS) -> RodParams:
    """``truth`` with each field of ``factors`` multiplied by its factor."""
    return truth.replace(**{name: getattr(truth, name) * factor for name, factor in factors.items()})


def model_quality(
    identified: RodParams,
    upright: TrajectoryDataset,
    hanging: Optional[TrajectoryDataset] = None,
    networks: Optional[Mapping[str, Any]] = None,
    horizon_s: float = 2.0,
    stride: int = 10,
    max_tilt_rad: float = 0.3,
    hanging_horizon_s: float = 1.0,
    start_state: str = "recorded",
    lookback_s: float = 0.1,
) -> dict[str, Any]:
    """The model-quality table on held-out simulated data.

    Parameters
    ----------
    identified : RodParams
        The grey-box model's parameters.
    upright : TrajectoryDataset
        Held-out babbling near upright (simulated PRB: recorded joint states and ``plant_params``).
    hanging : TrajectoryDataset, optional
        Held-out babbling around the hanging equilibrium (e.g. :data:`HANGING_PROTOCOL`).
    networks : mapping, optional
        Learned dynamics models by label.
    horizon_s, stride, max_tilt_rad
        Rollouts for the valid prediction time: ``horizon_s`` long, from every ``stride``-th sample whose tip
        angle is within ``max_tilt_rad`` of upright (the same samples for every model: from the largest history).
    hanging_horizon_s : float
        Horizon of the hanging-regime tip error [s].
    start_state : {"recorded", "estimated"}
        The grey-box rollouts start from the recorded joint state (simulated PRB data: the parameter error
        alone), or from the state estimated from the observations of the preceding ``lookback_s``
        (:func:`softpend.sysid.greybox.estimate_joint_states`: any plant, what a rig can do).  The
        "simulator started 1e-4 rad off" yardstick needs recorded PRB joint states and is left out otherwise.

    Returns
    -------
    dict
        ``lyapunov_rate_per_s``, ``length_m``, ``rows`` (label -> ``valid_prediction_s``,
        ``valid_prediction_lyapunov``, ``censored_fraction``, ``hanging_tip_rmse_pct_length``, ``one_step_mse``,
        ``one_step_tip_rmse_m`` where measured), ``curves`` (label -> RMS tip error [m] against ``horizon_s``),
        ``horizon_s`` (the curves' time axis [s]) and ``n_rollouts``.
    """
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

    def grey_errors(data: TrajectoryDataset, starts: np.ndarray, n_steps: int) -> np.ndarray:
        if start_state == "recorded":
            return prb_rollout_tip_errors(identified, data, starts, n_steps)
        states = estimate_joint_states(identified, data, starts, lookback_s=lookback_s)
        return prb_rollout_tip_errors(identified, data, starts, n_steps, initial_states=states)

    def yardstick(data: TrajectoryDataset, starts: np.ndarray, n_steps: int) -> dict[str, np.ndarray]:
        if not recorded_prb:
            return {}
        return {
            YARDSTICK_LABEL: prb_rollout_tip_errors(truth, data, starts, n_steps, hub_offset_rad=YARDSTICK_OFFSET_RAD)
        }

    lam = upright_growth_rate_per_s(truth)
    length = truth.length_m
    dt = upright.dt_s
    steps = int(round(horizon_s / dt))
    first = max([lookback] + [m.layout.history for m in networks.values()])
    starts = rollout_starts(upright, steps, stride=stride, first=first, max_tilt_rad=max_tilt_rad)
    errors: dict[str, np.ndarray] = {
        "grey-box model": grey_errors(upright, starts, steps),
        **yardstick(upright, starts, steps),
    }
    for label, model in networks.items():
        errors[label] = network_rollout_tip_errors(model, upright, starts, steps)
    rows: dict[str, dict[str, float]] = {}
    for label, error in errors.items():
        vp = valid_prediction(error, dt, length, lyapunov_rate_per_s=lam)
        rows[label] = {
            "valid_prediction_s": vp.median_s,
            "valid_prediction_lyapunov": vp.median_lyapunov,
            "censored_fraction": float(np.mean(vp.censored)),
        }
    if hanging is not None:
        h_steps = int(round(hanging_horizon_s / hanging.dt_s))
        h_first = max([lookback] + [m.layout.history for m in networks.values()])
        h_starts = rollout_starts(hanging, h_steps, stride=stride, first=h_first)
        h_errors = {"grey-box model": grey_errors(hanging, h_starts, h_steps), **yardstick(hanging, h_starts, h_steps)}
        for label, model in networks.items():
            h_errors[label] = network_rollout_tip_errors(model, hanging, h_starts, h_steps)
        for label, error in h_errors.items():
            rows[label]["hanging_tip_rmse_pct_length"] = (
                100 * tip_rmse_at_s(error, hanging.dt_s, hanging_horizon_s) / length
            )
    if recorded_prb:
        one = prb_one_step_errors(identified, upright)
        rows["grey-box model"]["one_step_mse"] = one["mse"]
        rows["grey-box model"]["one_step_tip_rmse_m"] = one["one_step_tip_rmse_m"]
    if networks:
        from softpend.sysid.metrics import one_step_errors

        for label, model in networks.items():
            net = one_step_errors(model, upright)
            rows[label]["one_step_mse"] = net["mse"]
            rows[label]["one_step_tip_rmse_m"] = net.get("one_step_tip_rmse_m", float("nan"))
    curves = {label: np.sqrt(np.mean(error**2, axis=0)) for label, error in errors.items()}
    return {
        "lyapunov_rate_per_s": lam,
        "length_m": length,
        "rows": rows,
        "curves": curves,
        "horizon_s": np.arange(steps + 1) * dt,
        "n_rollouts": int(starts.shape[0]),
    }


def closed_loop_usefulness(
    identified: Mapping[str, RodParams],
    task: Optional[Task] = None,
    seeds: Optional[Sequence[int]] = None,
    tilt_rad: float = 0.2,
    duration_s: float = 5.0,
    swingup_duration_s: float = TEST_EPISODE_S,
) -> list[dict[str, Any]]:
    """LQR (joint state on the PRB plant, observations on others; from the straight rod tilted by ``tilt_rad``
    plus the task's start noise) and energy swing-up + LQR (from hanging) designed on each parameter set of ``identified`` (label -> params) and on
    ``task.rod`` ("true parameters"), each run on the task's true plant from the same fresh starts ``seeds``
    (default: the first ten of :data:`softpend.study.presets.REPORT_SEEDS`).

    Returns
    -------
    list of dict
        One row per design and start: ``designed_on``, ``controller``, ``start``, ``success_rate``,
        ``successes``, ``episodes``, ``upright_std_rad`` (median over the episodes).
    """
    from softpend.control.lqr import LQRController
    from softpend.control.swingup import EnergySwingUpController
    from softpend.evaluation import EvaluationSummary, evaluate_controller
    from softpend.study.presets import REPORT_SEEDS

    task = task if task is not None else Task()
    joint = task.plant == "prb"  # other plants (the beam): the observation-feedback versions of both designs
    seeds = [int(s) for s in (seeds if seeds is not None else REPORT_SEEDS[:10])]
    designs = {"true parameters": task.rod, **dict(identified)}
    rows: list[dict[str, Any]] = []
    upright_task = task.replace(start="upright")
    for label, params in designs.items():
        params = params.replace(torque_limit_nm=task.rod.torque_limit_nm)
        results = []
        for seed in seeds:
            offset = float(np.random.default_rng(seed).uniform(-1.0, 1.0)) * task.start_noise_rad
            lqr_controller = LQRController.from_params(params, state="joint" if joint else "observation")
            results += evaluate_controller(
                lqr_controller,
                upright_task,
                seeds=(seed,),
                duration_s=duration_s,
                initial_state=task.tilt_state(tilt_rad + offset),
            ).results
        lqr = EvaluationSummary(name="LQR", results=results)
        swing_controller = (
            EnergySwingUpController(params) if joint else EnergySwingUpController.for_observations(params)
        )
        swing = evaluate_controller(
            swing_controller,
            task.replace(start="hanging"),
            seeds=seeds,
            duration_s=swingup_duration_s,
            name="energy swing-up + LQR",
        )
        for summary, start in ((lqr, f"tilt {tilt_rad:g} rad"), (swing, "hanging")):
            rows.append(
                {
                    "designed_on": label,
                    "controller": summary.name,
                    "start": start,
                    "success_rate": summary.success_rate,
                    "successes": summary.successes,
                    "episodes": len(summary.results),
                    "upright_std_rad": summary.median("upright_std_rad"),
                }
            )
    return rows

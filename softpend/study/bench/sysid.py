"""System-identification speed and accuracy (``softpend bench --only sysid``).

Runs the default protocol end to end on one torch thread: babble 60 x 5 s (seed 0), train the default
full-information model and the limited-information model, babble 12 held-out trials (seed 12345) and
measure one-step and open-loop rollout errors on them (all held-out trials, and the near-upright ones
that had the stabilising feedback), then time batched rollouts.  Five models: the report's (full
information, state without history, 3 x 16), full information with 3 past frames (3 x 16 and 3 x 64),
limited information with 3 past frames, and :data:`BEST_FULL_CONFIG` (``model_best``, the published
Figure 3 setting).

Yardsticks (:func:`softpend.sysid.perturbed_simulator_errors`, the simulator itself as the "model"):

* ``simulator_1e-4rad_off_*``: restarted 1e-4 rad off in hub angle;
* ``simulator_one_best_model_step_*``: restarted with the hub rate off by as much as makes its first
  step miss the tip by the best model's one-step tip RMSE (``model_best_one_step_tip_rmse_m``), i.e.
  a perfect model that makes the best model's one-step error *once*, at the start;
* ``simulator_torque_noise_1e-4nm_*``: an unmodelled hub torque of 1e-4 N m rms (0.17 % of the
  limit), independent at every step.

Grey-box identification (:func:`greybox_figures`): :func:`softpend.sysid.greybox.identify` on the training data
with its default settings from :func:`softpend.study.greybox.perturbed_guess` (``identify_s``,
``greybox_max_param_error_pct_sim``), and the model-quality measures of :mod:`softpend.sysid.quality` on the
held-out trials and on held-out hanging babbling for the grey-box model and ``model_best`` (``greybox_*``,
``nn_*``); and on a dataset of the digital twin (:func:`greybox_twin_figures`: ``greybox_max_param_error_pct_twin``,
about 80 s of real-time babbling over the emulated link, then the identification).
"""

from __future__ import annotations

import time

import numpy as np
import torch

from softpend.sysid.babble import BabbleProtocol, babble
from softpend.sysid.dataset import TrajectoryDataset
from softpend.sysid.metrics import evaluate_model, hub_rate_offset_for_tip_error, perturbed_simulator_errors
from softpend.sysid.model import DynamicsEnsemble, DynamicsModel
from softpend.sysid.rollout import rollout
from softpend.sysid.training import TrainConfig, fit_dynamics_model
from softpend.torch_threads import one_torch_thread

#: Seed of the training data and of the held-out data.
TRAIN_SEED = 0
TEST_SEED = 12345
ROLLOUT_BATCH = 4096
ROLLOUT_STEPS = 100
#: The most accurate full-information setting measured (the fig03 notebook's full profile): 6 past
#: frames, 3 x 64, 600 epochs of the cosine schedule run to the end (the best validation weights kept).
BEST_FULL_CONFIG = TrainConfig(history=6, hidden_widths=(64, 64, 64), max_epochs=600, patience=600)


def rollout_steps_per_s(
    model: DynamicsModel | DynamicsEnsemble, batch: int = ROLLOUT_BATCH, steps: int = ROLLOUT_STEPS, repeats: int = 3
) -> float:
    """Model steps per second of :func:`softpend.sysid.rollout` on ``batch`` rows (best of ``repeats``)."""
    generator = torch.Generator().manual_seed(0)
    dtype = model.feature_mean.dtype if isinstance(model, DynamicsModel) else torch.float32
    x0 = torch.randn(batch, model.layout.dim, generator=generator, dtype=dtype) * 0.1
    torques = (torch.rand(batch, steps, generator=generator, dtype=dtype) * 2 - 1) * model.torque_limit_nm
    best = float("inf")
    with torch.inference_mode():
        rollout(model, x0, torques[:, :5])  # warm-up
        for _ in range(repeats):
            start = time.perf_counter()
            rollout(model, x0, torques, generator=generator)
            best = min(best, time.perf_counter() - start)
    return batch * steps / best


def bench_sysid() -> dict[str, float]:
    """Babbling rate, training time, rollout rate and held-out accuracy of the default pipeline."""
    with one_torch_thread():
        protocol = BabbleProtocol()
        start = time.perf_counter()
        data = babble(protocol, seed=TRAIN_SEED, progress=False)
        babble_s = time.perf_counter() - start
        test = babble(protocol.replace(n_trials=12), seed=TEST_SEED, progress=False)
        out: dict[str, float] = {
            "babble_default_protocol_s": babble_s,
            "babble_transitions_per_s": data.n_transitions / babble_s,
        }
        configs = (
            ("model", TrainConfig()),  # the report's state and network
            ("model_history3", TrainConfig(history=3)),
            ("model_wide", TrainConfig(history=3, hidden_widths=(64, 64, 64))),
            ("model_limited", TrainConfig(information="limited", history=3)),
            ("model_best", BEST_FULL_CONFIG),
        )
        # held-out trials with the stabilising feedback: the rod stays near upright
        upright = np.flatnonzero(np.array(test.metadata["protocol"]["feedback_trials"], dtype=bool))
        for prefix, config in configs:
            fit = fit_dynamics_model(data, config, progress=False)
            metrics = evaluate_model(fit.model, test)
            near = evaluate_model(fit.model, test, upright, horizons_s=(0.5, 1.0))
            out[f"{prefix}_upright_trials_tip_rmse_m_0.5s"] = near["tip_rmse_m@0.5s"]
            out[f"{prefix}_upright_trials_tip_rmse_m_1s"] = near["tip_rmse_m@1s"]
            out[f"{prefix}_train_s"] = fit.train_time_s
            for key in ("mse", "mse_trivial", "mse_normalised", "mse_normalised_trivial"):
                out[f"{prefix}_one_step_{key}"] = metrics[key]
            for h in ("0.5", "1", "2"):
                out[f"{prefix}_tip_rmse_m_{h}s"] = metrics[f"tip_rmse_m@{h}s"]
                out[f"{prefix}_phi_rmse_rad_{h}s"] = metrics[f"phi_rmse_rad@{h}s"]
                out[f"{prefix}_hold_tip_rmse_m_{h}s"] = metrics[f"hold_tip_rmse_m@{h}s"]
            out[f"{prefix}_tip_rmse_over_length_1s"] = metrics["tip_rmse_over_length@1s"]
            if prefix == "model":
                out["model_rollout_steps_per_s"] = rollout_steps_per_s(fit.model)
            if prefix == "model_wide":
                out["model_wide_rollout_steps_per_s"] = rollout_steps_per_s(fit.model)
            if prefix == "model_best":
                out["model_best_one_step_tip_rmse_m"] = metrics["one_step_tip_rmse_m"]
                best_model = fit.model
        out.update(simulator_yardsticks(test, out["model_best_one_step_tip_rmse_m"], BEST_FULL_CONFIG.history))
        out.update(greybox_figures(data, test, best_model))
        out.update(greybox_twin_figures())
        return {k: float(v) if np.isfinite(v) else float("nan") for k, v in out.items()}


def simulator_yardsticks(
    test: TrajectoryDataset, model_one_step_tip_m: float, history: int = 0, horizon_s: float = 2.0
) -> dict[str, float]:
    """The simulator-as-model yardsticks of the module docstring on held-out trials (tip RMSE [m] after
    one step and at 0.5, 1 and 2 s, those within ``horizon_s``).

    Parameters
    ----------
    test : TrajectoryDataset
        Simulated held-out trials.
    model_one_step_tip_m : float
        One-step tip RMSE of the model to compare with [m]; sets the hub-rate offset of the
        ``simulator_one_best_model_step`` run.
    history : int
        The model's past frames (the rollouts start where the model's do).
    horizon_s : float
        Longest rollout [s].
    """
    if not (np.isfinite(model_one_step_tip_m) and model_one_step_tip_m > 0):
        raise ValueError(f"model_one_step_tip_m must be positive, got {model_one_step_tip_m!r}")
    out: dict[str, float] = {}
    runs: dict[str, dict] = {"simulator_1e-4rad_off": dict(hub_offset_rad=1e-4)}
    rate_rad_s = hub_rate_offset_for_tip_error(test, model_one_step_tip_m, history)
    out["simulator_one_best_model_step_hub_rate_offset_rad_s"] = rate_rad_s
    runs["simulator_one_best_model_step"] = dict(hub_offset_rad=0.0, hub_rate_offset_rad_s=rate_rad_s)
    runs["simulator_torque_noise_1e-4nm"] = dict(hub_offset_rad=0.0, torque_noise_std_nm=1e-4, seed=0)
    for prefix, kwargs in runs.items():
        sim = perturbed_simulator_errors(test, horizon_s=horizon_s, history=history, **kwargs)
        out[f"{prefix}_one_step_tip_rmse_m"] = float(sim.tip_rmse_m[1])
        for h in ("0.5", "1", "2"):
            if float(h) <= horizon_s + 1e-9:
                out[f"{prefix}_tip_rmse_m_{h}s"] = sim.at(float(h))["tip_rmse_m"]
    return out


def greybox_figures(data: TrajectoryDataset, test: TrajectoryDataset, network: object = None) -> dict[str, float]:
    """Grey-box identification of the training data from :func:`softpend.study.greybox.perturbed_guess` and
    its model quality (:func:`softpend.study.greybox.model_quality`) on the held-out trials and on held-out
    hanging babbling (seed ``TEST_SEED + 1``), beside ``network`` (the best learned model, keys ``nn_*``).

    Keys: ``identify_s`` (wall time of :func:`softpend.sysid.greybox.identify` on ``data``, default settings),
    ``greybox_max_param_error_pct_sim`` (largest relative error of an estimated field [%]),
    ``greybox_max_param_std_pct`` (largest standard deviation relative to its estimate [%]),
    ``greybox_valid_prediction_ratio`` (median valid prediction time near upright over that of the simulator
    started 1e-4 rad off), ``greybox_valid_prediction_lyapunov``, ``simulator_1e-4rad_off_valid_prediction_s``,
    ``greybox_hanging_tip_rmse_1s_pct_length``, ``greybox_one_step_mse``, ``lyapunov_rate_per_s``;
    closed-loop usefulness (:func:`softpend.study.greybox.closed_loop_usefulness`, ten fresh starts):
    ``greybox_lqr_successes``, ``greybox_swingup_successes`` and the same designed on the true parameters
    (``true_params_*``), ``greybox_*_upright_std_ratio`` (median upright std over that of the true design); and
    ``nn_valid_prediction_lyapunov``, ``nn_valid_prediction_ratio``, ``nn_hanging_tip_rmse_1s_pct_length``.
    """
    from softpend.study.greybox import (
        HANGING_PROTOCOL,
        YARDSTICK_OFFSET_RAD,
        closed_loop_usefulness,
        model_quality,
        perturbed_guess,
    )
    from softpend.sysid.greybox import identify
    from softpend.task import Task

    truth = data.params
    assert truth is not None  # simulated babbling records its rod
    result = identify(data, initial_params=perturbed_guess(truth))
    errors = result.relative_errors(truth)
    hanging = babble(HANGING_PROTOCOL, params=truth, seed=TEST_SEED + 1, progress=False)
    networks = {"nn": network} if network is not None else {}
    quality = model_quality(result.params, test, hanging, networks=networks)
    rows = quality["rows"]
    grey = rows["grey-box model"]
    yardstick = rows[f"simulator started {YARDSTICK_OFFSET_RAD:g} rad off"]
    out = {
        "identify_s": result.identify_s,
        "identify_windows": float(result.n_windows),
        "greybox_max_param_error_pct_sim": 100 * max(errors.values()),
        "greybox_max_param_std_pct": 100 * max(result.std[n] / abs(v) for n, v in result.estimates.items()),
        "lyapunov_rate_per_s": quality["lyapunov_rate_per_s"],
        "simulator_1e-4rad_off_valid_prediction_s": yardstick["valid_prediction_s"],
        "greybox_valid_prediction_s": grey["valid_prediction_s"],
        "greybox_valid_prediction_lyapunov": grey["valid_prediction_lyapunov"],
        "greybox_valid_prediction_ratio": grey["valid_prediction_s"] / yardstick["valid_prediction_s"],
        "greybox_hanging_tip_rmse_1s_pct_length": grey["hanging_tip_rmse_pct_length"],
        "greybox_one_step_mse": grey["one_step_mse"],
    }
    usefulness = {
        (r["designed_on"], r["controller"]): r
        for r in closed_loop_usefulness({"grey-box": result.params}, Task(rod=truth))
    }
    for key, controller in (("lqr", "LQR"), ("swingup", "energy swing-up + LQR")):
        grey_row, true_row = usefulness[("grey-box", controller)], usefulness[("true parameters", controller)]
        out[f"greybox_{key}_successes"] = grey_row["successes"]
        out[f"true_params_{key}_successes"] = true_row["successes"]
        out[f"greybox_{key}_upright_std_ratio"] = grey_row["upright_std_rad"] / true_row["upright_std_rad"]
    if network is not None:
        nn = rows["nn"]
        out["nn_valid_prediction_s"] = nn["valid_prediction_s"]
        out["nn_valid_prediction_lyapunov"] = nn["valid_prediction_lyapunov"]
        out["nn_valid_prediction_ratio"] = nn["valid_prediction_s"] / yardstick["valid_prediction_s"]
        out["nn_hanging_tip_rmse_1s_pct_length"] = nn["hanging_tip_rmse_pct_length"]
    return out


def greybox_twin_figures(seed: int = 0, duration_s: float = 33.0) -> dict[str, float]:
    """Grey-box identification of a dataset from the digital twin (:func:`softpend.hardware.twin.run_twin_session`:
    the emulated serial link with latency and an encoder of finite resolution, the synthetic camera, the clock
    synchronisation), ``duration_s`` of babbling in trials of 5 s, from
    :func:`softpend.study.greybox.perturbed_guess` of the twin's rod; the five rod fields and the camera's delay
    against the encoder (``camera_delay_s``: what the clock synchronisation leaves, a few milliseconds, which
    biases the friction estimate by some 13 % when it is not estimated).

    Keys: ``greybox_max_param_error_pct_twin`` (the rod fields), ``greybox_twin_error_pct_<field>`` and
    ``greybox_twin_std_pct_<field>`` per rod field, ``greybox_twin_camera_delay_s``, ``greybox_twin_at_bounds``
    (fields that ended on a bound of the search), ``identify_twin_s``, ``twin_session_s``.
    """
    import tempfile

    from softpend.hardware.twin import run_twin_session
    from softpend.study.greybox import perturbed_guess
    from softpend.sysid.greybox import GREYBOX_PARAMETERS, GreyBoxConfig, identify

    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="softpend-bench-twin-") as workdir:
        session = run_twin_session(workdir, duration_s=duration_s, seed=seed, trial_length_s=5.0, progress=False)
        dataset = session.dataset
    session_s = time.perf_counter() - start
    truth = dataset.params
    assert truth is not None  # the twin's rod, given to build_rig_dataset
    config = GreyBoxConfig(parameters=GREYBOX_PARAMETERS + ("camera_delay_s",))
    result = identify(dataset, config, initial_params=perturbed_guess(truth))
    errors = result.relative_errors(truth)
    out = {
        "twin_session_s": session_s,
        "identify_twin_s": result.identify_s,
        "greybox_twin_camera_delay_s": result.camera_delay_s,
        "greybox_max_param_error_pct_twin": 100 * max(errors.values()),
        "greybox_twin_at_bounds": float(len(result.at_bounds)),
    }
    for name, error in errors.items():
        out[f"greybox_twin_error_pct_{name}"] = 100 * error
        out[f"greybox_twin_std_pct_{name}"] = 100 * result.std[name] / abs(result.estimates[name])
    return out

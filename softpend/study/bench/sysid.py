"""System-identification speed and accuracy (``softpend bench --only sysid``): babbling, five learned models on
held-out trials, the simulator-as-model yardsticks, and grey-box identification on simulated and twin data."""

from __future__ import annotations

import tempfile
import time

import numpy as np
import torch

from softpend.study import greybox as gb
from softpend.study.bench import best_times
from softpend.sysid.babble import BabbleProtocol, babble
from softpend.sysid.dataset import TrajectoryDataset
from softpend.sysid.greybox import GREYBOX_PARAMETERS, GreyBoxConfig, identify
from softpend.sysid.metrics import evaluate_model, hub_rate_offset_for_tip_error, perturbed_simulator_errors
from softpend.sysid.model import DynamicsEnsemble, DynamicsModel, rollout
from softpend.sysid.training import TrainConfig, fit_dynamics_model
from softpend.task import Task
from softpend.torch_threads import one_torch_thread

TRAIN_SEED = 0
TEST_SEED = 12345
ROLLOUT_BATCH = 4096
ROLLOUT_STEPS = 100
#: The fig03 notebook's full-information setting (``model_best``).
BEST_FULL_CONFIG = TrainConfig(history=6, hidden_widths=(64, 64, 64), max_epochs=600, patience=600)


def rollout_steps_per_s(model: DynamicsModel | DynamicsEnsemble) -> float:
    """Model steps per second of batched rollouts (best of 3)."""
    generator = torch.Generator().manual_seed(0)
    dtype = model.feature_mean.dtype if isinstance(model, DynamicsModel) else torch.float32
    x0 = torch.randn(ROLLOUT_BATCH, model.layout.dim, generator=generator, dtype=dtype) * 0.1
    limit = model.torque_limit_nm
    torques = (torch.rand(ROLLOUT_BATCH, ROLLOUT_STEPS, generator=generator, dtype=dtype) * 2 - 1) * limit
    with torch.inference_mode():
        rollout(model, x0, torques[:, :5])  # warm-up
        best, _ = best_times(lambda: rollout(model, x0, torques, generator=generator), 3)
    return ROLLOUT_BATCH * ROLLOUT_STEPS / best


def bench_sysid() -> dict[str, float]:
    """The ``sysid`` benchmark group (see the module docstring)."""
    with one_torch_thread():
        protocol, start = BabbleProtocol(), time.perf_counter()
        data = babble(protocol, seed=TRAIN_SEED, progress=False)
        babble_s = time.perf_counter() - start
        test = babble(protocol.replace(n_trials=12), seed=TEST_SEED, progress=False)
        out = {"babble_default_protocol_s": babble_s, "babble_transitions_per_s": data.n_transitions / babble_s}
        configs = (
            ("model", TrainConfig()),  # the report's state and network
            ("model_history3", TrainConfig(history=3)),
            ("model_wide", TrainConfig(history=3, hidden_widths=(64, 64, 64))),
            ("model_limited", TrainConfig(information="limited", history=3)),
            ("model_best", BEST_FULL_CONFIG),
        )
        upright = np.flatnonzero(np.array(test.metadata["protocol"]["feedback_trials"], dtype=bool))
        for prefix, config in configs:
            fit = fit_dynamics_model(data, config, progress=False)
            metrics = evaluate_model(fit.model, test)
            near = evaluate_model(fit.model, test, upright, horizons_s=(0.5, 1.0))
            out |= {f"{prefix}_upright_trials_tip_rmse_m_{h}s": near[f"tip_rmse_m@{h}s"] for h in ("0.5", "1")}
            out[f"{prefix}_train_s"] = fit.train_time_s
            keys = [f"{n}@{h}s" for h in ("0.5", "1", "2") for n in ("tip_rmse_m", "phi_rmse_rad", "hold_tip_rmse_m")]
            out |= {f"{prefix}_{k.replace('@', '_')}": metrics[k] for k in keys + ["tip_rmse_over_length@1s"]}
            keys = ["mse", "mse_trivial", "mse_normalised", "mse_normalised_trivial"]
            out |= {f"{prefix}_one_step_{key}": metrics[key] for key in keys}
            if prefix in ("model", "model_wide"):
                out[f"{prefix}_rollout_steps_per_s"] = rollout_steps_per_s(fit.model)
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
    """Tip RMSE [m] of the perturbed-simulator yardsticks on ``test`` after one step and at 0.5, 1, 2 s (within
    ``horizon_s``); ``model_one_step_tip_m`` sets ``simulator_one_best_model_step``'s hub-rate offset."""
    if not (np.isfinite(model_one_step_tip_m) and model_one_step_tip_m > 0):
        raise ValueError(f"model_one_step_tip_m must be positive, got {model_one_step_tip_m!r}")
    rate_rad_s = hub_rate_offset_for_tip_error(test, model_one_step_tip_m, history)
    out = {"simulator_one_best_model_step_hub_rate_offset_rad_s": rate_rad_s}
    runs: dict[str, dict] = {
        "simulator_1e-4rad_off": dict(hub_offset_rad=1e-4),
        "simulator_one_best_model_step": dict(hub_offset_rad=0.0, hub_rate_offset_rad_s=rate_rad_s),
        "simulator_torque_noise_1e-4nm": dict(hub_offset_rad=0.0, torque_noise_std_nm=1e-4, seed=0),
    }
    for prefix, kwargs in runs.items():
        sim = perturbed_simulator_errors(test, horizon_s=horizon_s, history=history, **kwargs)
        out[f"{prefix}_one_step_tip_rmse_m"] = float(sim.tip_rmse_m[1])
        for h in ("0.5", "1", "2"):
            if float(h) <= horizon_s + 1e-9:
                out[f"{prefix}_tip_rmse_m_{h}s"] = sim.at(float(h))["tip_rmse_m"]
    return out


def greybox_figures(data: TrajectoryDataset, test: TrajectoryDataset, network: object) -> dict[str, float]:
    """Grey-box identification of ``data`` from the perturbed guess, its parameter errors, model quality on held-out
    data (beside ``network``: keys ``nn_*``) and closed-loop usefulness."""
    truth = data.params
    assert truth is not None  # simulated babbling records its rod
    result = identify(data, initial_params=gb.perturbed_guess(truth))
    errors = result.relative_errors(truth)
    hanging = babble(gb.HANGING_PROTOCOL, params=truth, seed=TEST_SEED + 1, progress=False)
    quality = gb.model_quality(result.params, test, hanging, networks={"nn": network})
    rows = quality["rows"]
    yardstick = rows[gb.YARDSTICK_LABEL]
    out = {
        "identify_s": result.identify_s,
        "identify_windows": float(result.n_windows),
        "greybox_max_param_error_pct_sim": 100 * max(errors.values()),
        "greybox_max_param_std_pct": 100 * max(result.std[n] / abs(v) for n, v in result.estimates.items()),
        "lyapunov_rate_per_s": quality["lyapunov_rate_per_s"],
        "simulator_1e-4rad_off_valid_prediction_s": yardstick["valid_prediction_s"],
        "greybox_one_step_mse": rows["grey-box model"]["one_step_mse"],
    }
    for prefix, row in (("greybox", rows["grey-box model"]), ("nn", rows["nn"])):
        out |= {f"{prefix}_{k}": row[k] for k in ("valid_prediction_s", "valid_prediction_lyapunov")}
        out[f"{prefix}_valid_prediction_ratio"] = row["valid_prediction_s"] / yardstick["valid_prediction_s"]
        out[f"{prefix}_hanging_tip_rmse_1s_pct_length"] = row["hanging_tip_rmse_pct_length"]
    closed_loop = gb.closed_loop_usefulness({"grey-box": result.params}, Task(rod=truth))
    usefulness = {(r["designed_on"], r["controller"]): r for r in closed_loop}
    for key, controller in (("lqr", "LQR"), ("swingup", "energy swing-up + LQR")):
        grey_row, true_row = usefulness[("grey-box", controller)], usefulness[("true parameters", controller)]
        out[f"greybox_{key}_successes"] = grey_row["successes"]
        out[f"true_params_{key}_successes"] = true_row["successes"]
        out[f"greybox_{key}_upright_std_ratio"] = grey_row["upright_std_rad"] / true_row["upright_std_rad"]
    return out


def greybox_twin_figures(seed: int = 0, duration_s: float = 33.0) -> dict[str, float]:
    """Grey-box identification (rod fields and camera delay) of ``duration_s`` of babbling on the digital twin."""
    from softpend.hardware.twin import run_twin_session

    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="softpend-bench-twin-") as workdir:
        session = run_twin_session(workdir, duration_s=duration_s, seed=seed, trial_length_s=5.0, progress=False)
        dataset = session.dataset
    session_s = time.perf_counter() - start
    truth = dataset.params
    assert truth is not None  # the twin's rod, given to build_rig_dataset
    config = GreyBoxConfig(parameters=GREYBOX_PARAMETERS + ("camera_delay_s",))
    result = identify(dataset, config, initial_params=gb.perturbed_guess(truth))
    errors = result.relative_errors(truth)
    out = {"twin_session_s": session_s, "identify_twin_s": result.identify_s}
    out |= {
        "greybox_twin_camera_delay_s": result.camera_delay_s,
        "greybox_twin_at_bounds": float(len(result.at_bounds)),
    }
    out["greybox_max_param_error_pct_twin"] = 100 * max(errors.values())
    for name, error in errors.items():
        out[f"greybox_twin_error_pct_{name}"] = 100 * error
        out[f"greybox_twin_std_pct_{name}"] = 100 * result.std[name] / abs(result.estimates[name])
    return out

"""Control and rig benchmarks: classical control on the default rod (``softpend bench --only control``); each
controller of :func:`controller_factories` from fresh hanging starts on the digital twin, in the ideal simulator and on
perturbed rods (``--only rig_control``); the plant seconds each route needs to balance (``--only data_efficiency``);
tracker speed and accuracy and the rig loop's jitter (``--only hardware``); ``softpend rig commission`` on the twins of
five unknown rods (seeds no code was tuned on, ``--only commission``): the worst fresh-start success on the nominal and
the harsh twin, the excitation seconds, the largest identification error (infinite when a parameter was held at the
guess) and the plant seconds each controller class (swing-up + LQR, DQN, DQN-MBPO, PILCO) used."""

from __future__ import annotations

import dataclasses
import math
import statistics
import tempfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

from softpend.evaluation import HOLD_STD_RAD, evaluate_controller
from softpend.plant import RodParams
from softpend.study import data_efficiency as de
from softpend.study.bench import best_times
from softpend.task import Task

SWINGUP_SEEDS = (0, 1, 2, 3, 4)
TILT_RAD = 0.2


def bench_control() -> dict[str, float]:
    """LQR from a 0.2 rad tilt (joint state, observations, learned model): upright and hold std; its region of
    attraction; energy swing-up + LQR from hanging: worst and median swing-up time, worst upright std."""
    import torch

    from softpend.control.learned import lqr_from_learned_model
    from softpend.control.lqr import LQRController
    from softpend.control.region import region_of_attraction_rad
    from softpend.control.swingup import EnergySwingUpController
    from softpend.sysid import babble
    from softpend.sysid.training import fit_dynamics_model

    torch.set_num_threads(1)
    params = RodParams()
    task = Task(rod=params)
    upright, tilt = task.replace(start="upright"), task.tilt_state(TILT_RAD)

    def from_tilt(controller):
        return evaluate_controller(controller, upright, seeds=(0,), duration_s=10.0, initial_state=tilt).results[0]

    lqr = LQRController.from_params(params)
    run = from_tilt(lqr)
    out = {
        "lqr_upright_std_rad": run.upright_std_rad,
        "lqr_hold_std_rad": float(np.sqrt(np.mean(run.theta_rad[-500:] ** 2))),
    }
    observation = LQRController.from_params(params, state="observation")
    out["lqr_observation_upright_std_rad"] = from_tilt(observation).upright_std_rad
    out["lqr_region_of_attraction_rad"] = region_of_attraction_rad(lqr, task).largest_recovered_rad
    swing = evaluate_controller(EnergySwingUpController(params), task, seeds=SWINGUP_SEEDS, duration_s=10.0)
    out["swingup_lqr_time_s"] = float(max(r.swing_up_time_s for r in swing.results))
    out["swingup_lqr_median_time_s"] = swing.median("swing_up_time_s")
    out["swingup_lqr_std_rad"] = float(max(r.upright_std_rad for r in swing.results))
    model = fit_dynamics_model(babble(params=params, seed=0, progress=False), progress=False).model
    out["learned_lqr_upright_std_rad"] = from_tilt(lqr_from_learned_model(model, params)).upright_std_rad
    return out


N_STARTS = 10
DURATION_S = 10.0
#: Spread of the rod-parameter changes of ``rig_perturbed_success_<c>``.
PERTURBATION = 0.15


def controller_factories() -> dict[str, Callable[[], tuple[Any, Any]]]:
    """``name -> () -> (controller, task)``; the learned ones are the final policies of the book's first seed."""
    from softpend.control.swingup import EnergySwingUpController
    from softpend.study.head_to_head import pilco_runs
    from softpend.study.presets import PILCO, PILCO_BOOK, RL_BOOK, TASK
    from softpend.study.rig_runs import learned_controller
    from softpend.study.rl_runs import figure_configs, figure_runs, run_folder

    def rl(algo: str):
        seed = RL_BOOK.seeds[0]
        figure_runs(RL_BOOK.episodes_dqn, RL_BOOK.episodes_mbpo, (seed,), RL_BOOK.runs_root, progress=True)
        return learned_controller(run_folder(RL_BOOK.runs_root, algo, seed, figure_configs()[algo]), "final")[:2]

    def pilco():
        seed = PILCO_BOOK.seeds[0]
        pilco_runs(PILCO, (seed,), PILCO_BOOK.runs_root, progress=True)
        return learned_controller(
            run_folder(PILCO_BOOK.runs_root, "pilco", seed, dataclasses.replace(PILCO, seed=seed))
        )[:2]

    swingup = lambda: (EnergySwingUpController(TASK.rod, dt_s=TASK.dt_s), TASK)  # noqa: E731
    return {"swingup_lqr": swingup, "dqn": lambda: rl("dqn"), "mbpo": lambda: rl("mbpo"), "pilco": pilco}


def bench_rig_control() -> dict[str, float]:
    """Per controller: success on the nominal twin, in the ideal simulator and on perturbed rods, the drop from
    simulator to twin, and the successes' worst upright std, median swing-up time and median chatter."""
    from softpend.study.fresh_starts import perturbed_rod_row
    from softpend.study.presets import REPORT_SEEDS
    from softpend.study.rig_runs import RigCondition, simulator_starts, summary_rows, twin_start

    seeds, condition, out = REPORT_SEEDS[:N_STARTS], RigCondition("nominal twin"), dict[str, float]()
    with tempfile.TemporaryDirectory() as tmp:
        for name, make in controller_factories().items():
            controller, task = make()
            task = task.replace(start_noise_rad=0.05)
            folders = {seed: Path(tmp) / f"{name}-{seed}" for seed in seeds}
            rows = [
                twin_start(controller, name, task, condition, s, DURATION_S, folders[s], HOLD_STD_RAD) for s in seeds
            ]
            sim = simulator_starts(controller, name, task, seeds, DURATION_S, success_std_rad=HOLD_STD_RAD)
            twin, ideal = summary_rows(rows)[0], summary_rows(sim)[0]
            for key in ("success_rate", "upright_std_rad", "swing_up_time_s", "torque_chatter_nm_per_s"):
                out[f"rig_{key.removesuffix('_rate')}_{name}"] = twin[key]
            out[f"rig_sim_success_{name}"] = ideal["success_rate"]
            perturbed = perturbed_rod_row(controller, task, PERTURBATION, report_seeds=seeds, duration_s=DURATION_S)
            out[f"rig_perturbed_success_{name}"] = perturbed["balanced_rate"]
            out[f"rig_success_drop_pp_{name}"] = 100.0 * (ideal["success_rate"] - twin["success_rate"])
    return out


def bench_data_efficiency(seeds: tuple[int, ...] = tuple(range(10))) -> dict[str, float]:
    """Median and worst plant seconds to balance the fresh report starts, and seeds balanced, of the grey-box route
    (``greybox_beam``: PRB model fitted to beam data) and the planner (``mpc``: PRB-residual model, ``mpc_blackbox``:
    black-box ensemble, ``mpc_beam``: on the beam); the planner's plant seconds over PILCO's (NaN unless the book's
    PILCO runs are trained); ``mpc_rig_*``: the seed-0 planner on the nominal twin from the ``rig_control`` starts."""
    from softpend.study.presets import PILCO_BOOK, REPORT_SEEDS
    from softpend.study.rig_runs import planner_twin_figures

    figures = de.greybox_route_figures(de.greybox_route_rows("prb", seeds), "greybox", 5.0)
    figures.update(de.greybox_route_figures(de.greybox_route_rows("beam", seeds), "greybox_beam", 15.0))
    mpc = de.planner_rows("residual", seeds)
    figures.update(de.greybox_route_figures(mpc, "mpc", 15.0))
    figures.update(de.greybox_route_figures(de.planner_rows("ensemble", seeds), "mpc_blackbox", 15.0))
    figures.update(de.greybox_route_figures(de.planner_rows("residual", seeds, plant="beam"), "mpc_beam", 30.0))
    pilco = de.pilco_rows_if_trained(seeds, PILCO_BOOK.runs_root)
    figures["pilco_book_runs_found"] = float(pilco is not None)
    mpc_s = {r["seed"]: r["real_s_to_balance"] for r in mpc}
    ratio = math.nan if pilco is None else de.paired_ratio(mpc_s, {r["seed"]: r["plant_s_to_balance"] for r in pilco})
    figures["mpc_over_pilco_real_s_ratio"] = ratio
    rig = planner_twin_figures(REPORT_SEEDS[:N_STARTS], DURATION_S)
    for key in ("successes", "step_ms_p95", "step_ms_max", "control_period_ms", "steps_over_period"):
        figures[f"mpc_rig_{key}"] = float(rig[key])
    return figures


N_FRAMES = 300
LOOP_SECONDS = 5.0


def _tracker_figures(effects, seed: int, trajectory) -> tuple[float, float, float, float]:
    """(RMS error [px], frames/s with the search window, frames/s searching whole frames, lost frames)."""
    from softpend.vision.accuracy import tracking_errors
    from softpend.vision.tracker import TipTracker

    errors, frames = tracking_errors(trajectory, effects, N_FRAMES, seed, keep_frames=True)
    fps = []
    for radius in (TipTracker().search_radius_px, None):  # the search window, whole frames
        track = lambda: list(map(TipTracker(search_radius_px=radius).track, frames))  # noqa: E731,B023  (a fresh tracker)
        fps.append(len(frames) / best_times(track, 3)[0])
    return errors.rmse_px, fps[0], fps[1], float(errors.lost.sum())


def _rig_loop_jitter() -> dict[str, float]:
    """Command-period figures of the closed loop against the emulator in its own process on a pseudo-terminal."""
    from softpend.control.swingup import EnergySwingUpController
    from softpend.hardware.closed_loop import run_closed_loop
    from softpend.hardware.driver import MotorLink
    from softpend.hardware.emulator import EmulatorProcess, RigConfig
    from softpend.hardware.estimator import RigStateEstimator

    rig = RigConfig()
    task, controller = rig.task, EnergySwingUpController(rig.task.rod, dt_s=rig.task.dt_s)
    with EmulatorProcess(rig) as emulator:
        with MotorLink(emulator.port, torque_limit_nm=task.torque_limit_nm, timeout_s=1.0) as link:
            result = run_closed_loop(link, controller, RigStateEstimator(task), LOOP_SECONDS)
    periods_ms = result.command_periods_s * 1e3
    figures = {"rig_loop_jitter_ms": result.jitter_ms_p95, "rig_loop_dropped_states": float(result.dropped_states)}
    figures |= {f"rig_loop_period_ms_{name}": float(f(periods_ms)) for name, f in (("mean", np.mean), ("max", np.max))}
    return figures | {"rig_loop_late_command_fraction": result.late_commands / max(result.samples, 1)}


def bench_hardware() -> dict[str, float]:
    """Tracker speed and accuracy on clean and noisy rendered frames, and the rig loop's jitter."""
    import cv2

    from softpend.vision.accuracy import babbling_trajectory
    from softpend.vision.camera import CameraEffects

    cv2.setNumThreads(1)
    trajectory = babbling_trajectory(N_FRAMES + 2)
    out: dict[str, float] = {}
    for name, effects, seed in (("clean", CameraEffects(), 0), ("noisy", CameraEffects.noisy(), 1)):
        fps = "tracker_fps_640x480" + ("_noisy" if seed else "")
        rmse, out[fps], out[f"{fps}_full_frame"], lost = _tracker_figures(effects, seed, trajectory)
        out[f"tracker_rmse_px_{name}"], out[f"tracker_lost_frames_{name}"] = rmse, lost
    return out | _rig_loop_jitter()


#: The unknown rods of the commissioning figures (9001-9005 and 9101-9105 were looked at while it was fixed).
UNKNOWN_ROD_SEEDS = (9201, 9202, 9203, 9204, 9205)
#: The figures' names of the commissioned classes that differ from their names in the report.
BENCH_NAMES = {"swingup": "swingup_lqr"}


def commission_figures(reports: list[dict]) -> dict[str, float]:
    """The group's figures from the commissioning reports of :func:`softpend.study.commission.commission`: the
    worst class on the worst rod per condition, and per class the median plant seconds."""
    from softpend.study.commission import identification_errors

    successes: dict[str, list[float]] = {}
    plant_s: dict[str, list[float]] = {}
    errors = []
    for report in reports:
        for name, entry in report["classes"].items():
            for row in entry["verification"]:
                successes.setdefault(row["condition"], []).append(10.0 * row["successes"] / row["starts"])
            plant_s.setdefault(BENCH_NAMES.get(name, name), []).append(entry["plant_s"])
        errors += identification_errors(report)
    return {
        "commission_success_min": min(successes["nominal"]),
        "commission_harsh_success_min": min(successes["harsh"]),
        "commission_identify_s": max(r["plant_s"]["excite"] for r in reports),
        "commission_max_param_error_pct": 100.0 * max(errors),
        **{f"commission_plant_s_{name}": statistics.median(values) for name, values in plant_s.items()},
    }


def bench_commission() -> dict[str, float]:
    """The ``commission`` benchmark group (see the module docstring)."""
    from softpend.study.commission import commissioned_rods

    with tempfile.TemporaryDirectory(prefix="softpend-bench-commission-") as work:
        return commission_figures(commissioned_rods(work, UNKNOWN_ROD_SEEDS))

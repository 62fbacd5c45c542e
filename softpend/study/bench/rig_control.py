"""Closed-loop figures on the digital twin (``softpend bench --only rig_control``).

Each controller class runs through the whole rig stack on the digital twin, in simulated time -- the emulated
device behind the real protocol bytes and driver, the synthetic live camera filming the emulator (60 frames/s, 20 ms latency, the nominal
:meth:`~softpend.vision.camera.CameraEffects.rig` noise), the Algorithm 1 tracker, the state estimator, the
4096-count encoder -- from N_STARTS fresh hanging starts (the first of
:data:`softpend.study.presets.REPORT_SEEDS`, ``start_noise_rad`` 0.05), DURATION_S each, and in the ideal
simulator from the same starts (:func:`softpend.study.rig_runs.simulator_starts`).  The loop's real-time figures
(command jitter, late commands on a pseudo-terminal) are in ``softpend bench --only hardware``.  A start succeeds when the
rod's true tip (the emulator's truth log) swings up and holds with upright std <= :data:`softpend.evaluation.HOLD_STD_RAD`.

The controllers (:data:`CONTROLLERS`): ``swingup_lqr``, the energy swing-up handing over to the LQR on the
joint state the estimator provides; ``dqn``, ``mbpo`` and ``pilco``, the *final* agent or policy of the first
training seed of the book's runs (``RL_BOOK``, ``PILCO_BOOK``: reused when present, trained otherwise).  No
run is picked by its results: the first seed is the one measured.
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from pathlib import Path
from typing import Any, Callable

import numpy as np

from softpend.evaluation import HOLD_STD_RAD

N_STARTS = 10
DURATION_S = 10.0
#: Spread of the rod-parameter changes of ``rig_perturbed_success_<c>`` (+-15 %).
PERTURBATION = 0.15
#: Benchmark names of the controller classes, in the order they run.
CONTROLLERS = ("swingup_lqr", "dqn", "mbpo", "pilco")


def controller_factories() -> dict[str, Callable[[], tuple[Any, Any]]]:
    """``name -> () -> (controller, task)`` for every entry of :data:`CONTROLLERS`."""
    from softpend.control.swingup import EnergySwingUpController
    from softpend.study.head_to_head import pilco_runs
    from softpend.study.presets import PILCO, PILCO_BOOK, RL_BOOK, TASK
    from softpend.study.rig_runs import learned_controller
    from softpend.study.rl_runs import figure_configs, figure_runs, run_folder

    def swingup():
        return EnergySwingUpController(TASK.rod, dt_s=TASK.dt_s), TASK

    def rl(algo: str):
        def make():
            seed = RL_BOOK.seeds[0]
            figure_runs(RL_BOOK.episodes_dqn, RL_BOOK.episodes_mbpo, (seed,), RL_BOOK.runs_root, progress=True)
            config = figure_configs()[algo]
            controller, task, _ = learned_controller(run_folder(RL_BOOK.runs_root, algo, seed, config), "final")
            return controller, task

        return make

    def pilco():
        seed = PILCO_BOOK.seeds[0]
        pilco_runs(PILCO, (seed,), PILCO_BOOK.runs_root, progress=True)
        folder = run_folder(PILCO_BOOK.runs_root, "pilco", seed, dataclasses.replace(PILCO, seed=seed))
        controller, task, _ = learned_controller(folder)
        return controller, task

    return {"swingup_lqr": swingup, "dqn": rl("dqn"), "mbpo": rl("mbpo"), "pilco": pilco}


def bench_rig_control(controllers: tuple[str, ...] = CONTROLLERS, n_starts: int = N_STARTS) -> dict[str, float]:
    """Per controller ``c``: ``rig_success_<c>`` (fraction of starts on the nominal twin),
    ``rig_upright_std_rad_<c>`` (worst start that succeeded), ``rig_swing_up_time_s_<c>`` (median over
    successes), ``rig_torque_chatter_nm_per_s_<c>`` (median), ``rig_sim_success_<c>`` (the same starts in the
    ideal simulator), ``rig_success_drop_pp_<c>`` (simulator minus twin, percentage points) and
    ``rig_perturbed_success_<c>`` (the same starts in the simulator, each on a rod whose mass, stiffness, damping,
    hub friction and torque limit differ from the model by up to +-15 %,
    :func:`softpend.study.fresh_starts.perturbed_rod_row`)."""
    from softpend.study.fresh_starts import perturbed_rod_row
    from softpend.study.presets import REPORT_SEEDS
    from softpend.study.rig_runs import RigCondition, simulator_starts, twin_start

    factories = controller_factories()
    unknown = [c for c in controllers if c not in factories]
    if unknown:
        raise ValueError(f"unknown rig controller(s) {unknown}; choose from {sorted(factories)}")
    seeds = REPORT_SEEDS[:n_starts]
    condition = RigCondition("nominal twin")
    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in controllers:
            controller, task = factories[name]()
            task = task.replace(start_noise_rad=0.05)
            rows = [
                twin_start(
                    controller,
                    name,
                    task,
                    condition,
                    seed,
                    DURATION_S,
                    Path(tmp) / f"{name}-{seed}",
                    success_std_rad=HOLD_STD_RAD,
                )
                for seed in seeds
            ]
            sim = simulator_starts(controller, name, task, seeds, DURATION_S, success_std_rad=HOLD_STD_RAD)
            good = [r for r in rows if r["success"]]
            twin_rate = len(good) / len(rows)
            sim_rate = sum(r["success"] for r in sim) / len(sim)
            out[f"rig_success_{name}"] = twin_rate
            out[f"rig_upright_std_rad_{name}"] = float(max(r["upright_std_rad"] for r in good)) if good else math.nan
            out[f"rig_swing_up_time_s_{name}"] = (
                float(np.median([r["swing_up_time_s"] for r in good])) if good else math.nan
            )
            chatter = [r["torque_chatter_nm_per_s"] for r in rows if math.isfinite(r["torque_chatter_nm_per_s"])]
            out[f"rig_torque_chatter_nm_per_s_{name}"] = float(np.median(chatter)) if chatter else math.nan
            out[f"rig_sim_success_{name}"] = sim_rate
            perturbed = perturbed_rod_row(controller, task, PERTURBATION, report_seeds=seeds, duration_s=DURATION_S)
            out[f"rig_perturbed_success_{name}"] = perturbed["balanced_rate"]
            out[f"rig_success_drop_pp_{name}"] = 100.0 * (sim_rate - twin_rate)
    return out

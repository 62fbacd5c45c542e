"""Closed-loop figures (``softpend bench --only rig_control``): each controller of :func:`controller_factories` from
fresh hanging starts on the digital twin, in the ideal simulator and on perturbed rods."""

from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path
from typing import Any, Callable

from softpend.evaluation import HOLD_STD_RAD

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

    return {
        "swingup_lqr": lambda: (EnergySwingUpController(TASK.rod, dt_s=TASK.dt_s), TASK),
        "dqn": lambda: rl("dqn"),
        "mbpo": lambda: rl("mbpo"),
        "pilco": pilco,
    }


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
            folder = Path(tmp)
            rows = [
                twin_start(controller, name, task, condition, seed, DURATION_S, folder / f"{name}-{seed}", HOLD_STD_RAD)
                for seed in seeds
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

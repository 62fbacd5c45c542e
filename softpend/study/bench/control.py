"""Classical-control figures on the default rod (``softpend bench --only control``)."""

from __future__ import annotations

import numpy as np

from softpend.evaluation import evaluate_controller
from softpend.plant import RodParams
from softpend.task import Task

SWINGUP_SEEDS = (0, 1, 2, 3, 4)
TILT_RAD = 0.2


def bench_control(include_learned: bool = True) -> dict[str, float]:
    """LQR from a 0.2 rad tilt (joint state, observations, learned model): upright and hold std; its region of
    attraction; energy swing-up + LQR from hanging: worst and median swing-up time, worst upright std."""
    import torch

    from softpend.control.learned import lqr_from_learned_model
    from softpend.control.lqr import LQRController
    from softpend.control.region import region_of_attraction_rad
    from softpend.control.swingup import EnergySwingUpController

    torch.set_num_threads(1)
    params = RodParams()
    out: dict[str, float] = {}
    lqr = LQRController.from_params(params)
    task = Task(rod=params)
    upright = task.replace(start="upright")
    tilt = task.tilt_state(TILT_RAD)
    run = evaluate_controller(lqr, upright, seeds=(0,), duration_s=10.0, initial_state=tilt).results[0]
    out["lqr_upright_std_rad"] = run.upright_std_rad
    out["lqr_hold_std_rad"] = float(np.sqrt(np.mean(run.theta_rad[-500:] ** 2)))
    obs_lqr = LQRController.from_params(params, state="observation")
    out["lqr_observation_upright_std_rad"] = (
        evaluate_controller(obs_lqr, upright, seeds=(0,), duration_s=10.0, initial_state=tilt)
        .results[0]
        .upright_std_rad
    )
    out["lqr_region_of_attraction_rad"] = region_of_attraction_rad(lqr, task).largest_recovered_rad
    swing = evaluate_controller(EnergySwingUpController(params), task, seeds=SWINGUP_SEEDS, duration_s=10.0)
    out["swingup_lqr_time_s"] = float(max(r.swing_up_time_s for r in swing.results))
    out["swingup_lqr_median_time_s"] = swing.median("swing_up_time_s")
    out["swingup_lqr_std_rad"] = float(max(r.upright_std_rad for r in swing.results))
    if include_learned:
        from softpend.sysid import babble
        from softpend.sysid.training import fit_dynamics_model

        dataset = babble(params=params, seed=0, progress=False)
        model = fit_dynamics_model(dataset, progress=False).model
        learned = lqr_from_learned_model(model, params)
        out["learned_lqr_upright_std_rad"] = (
            evaluate_controller(learned, upright, seeds=(0,), duration_s=10.0, initial_state=tilt)
            .results[0]
            .upright_std_rad
        )
    return out

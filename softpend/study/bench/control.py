"""Classical-control figures on the default rod (``softpend bench --only control``)."""

from __future__ import annotations

import numpy as np

from softpend.evaluation import evaluate_controller
from softpend.plant import RodParams
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

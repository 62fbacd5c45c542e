"""Classical-control figures (``softpend bench --only control``).

Every figure goes through :func:`softpend.evaluation.evaluate_controller` on the default rod (n = 4,
dt = 0.01 s, torque limit 0.06 N m):

* ``lqr_upright_std_rad`` -- LQR from the true model (joint state), straight rod released at rest from a
  0.2 rad tilt, 10 s: the evaluation's ``upright_std_rad`` (RMS tip angle after it first stays within
  0.2 rad for 1 s; the recovery transient is included);
* ``lqr_hold_std_rad`` -- the same run, RMS tip angle over the last 5 s (holding only);
* ``lqr_observation_upright_std_rad`` -- the same with the LQR on observations only;
* ``lqr_region_of_attraction_rad`` -- largest initial tilt the true-model LQR recovers from;
* ``swingup_lqr_time_s`` / ``swingup_lqr_std_rad`` -- energy swing-up plus LQR from hanging, worst case
  over start seeds 0-4 (the evaluation's start noise): the largest swing-up time and upright std;
* ``swingup_lqr_median_time_s`` -- median swing-up time over those seeds;
* ``learned_lqr_upright_std_rad`` -- LQR designed on a learned model (report-protocol babbling, 60 x 5 s,
  seed 0; default 3 x 16 network) applied to the true plant from the 0.2 rad tilt; ``inf``-free: a fall
  shows as a large std.
"""

from __future__ import annotations

import numpy as np

from softpend.evaluation import evaluate_controller
from softpend.plant import RodParams
from softpend.task import Task

#: Start seeds of the swing-up benchmark.
SWINGUP_SEEDS = (0, 1, 2, 3, 4)
TILT_RAD = 0.2


def bench_control(include_learned: bool = True) -> dict[str, float]:
    """Measure the classical baselines (see the module docstring)."""
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

"""``softpend bench --only pilco``: real plant seconds PILCO needs to balance the soft rod, and its compute.

* ``pilco_real_s_to_balance`` -- training plant seconds (random trial plus policy trials) up to the first
  policy whose test on the true plant (shared :func:`softpend.evaluation.evaluate_controller`, three
  start-noise seeds, 8 s from hanging) swings up on every seed with ``upright_std_rad <= 0.1``; ``inf`` if
  no policy within the trial budget does.  Target: < 90 s.
* ``pilco_train_wall_s`` -- wall-clock seconds of that whole run (model fits, policy searches, trials and
  the test episodes), single-threaded torch.  Target: < 900 s on the project's 2-core machine.
* ``pilco_trials``, ``pilco_final_upright_std_rad`` -- trials run and the last policy's worst-seed error.

The run uses the default :class:`~softpend.pilco.loop.PilcoConfig` (the project's soft rod, seed 0) and is
saved to ``runs/bench-pilco`` for inspection; it is always rerun, since its wall time is the measurement.
"""

from __future__ import annotations

import torch

from .loop import PilcoConfig, run_pilco

ROOT = "runs/bench-pilco"


def bench_pilco() -> dict[str, float]:
    """The "pilco" benchmark group (see the module docstring)."""
    torch.set_num_threads(1)
    result = run_pilco(PilcoConfig(seed=0), progress=True)
    result.save(ROOT)
    return {
        "pilco_real_s_to_balance": result.real_seconds_to_balance,
        "pilco_train_wall_s": result.train_wall_s,
        "pilco_trials": float(len(result.records)),
        "pilco_final_upright_std_rad": result.records[-1].eval_upright_std_rad,
    }

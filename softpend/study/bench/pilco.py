"""``softpend bench --only pilco``: real plant seconds PILCO needs to balance the soft rod, and its compute.

The default :class:`~softpend.pilco.loop.PilcoConfig` (the project's soft rod) runs once per seed of
:data:`SEEDS`; the targets below hold for *every* seed, so the headline figures are the worst seed's:

* ``pilco_real_s_to_balance`` -- training plant seconds (random trial plus policy trials) up to the first
  policy whose test on the true plant (shared :func:`softpend.evaluation.evaluate_controller`, three
  start-noise seeds, 8 s from hanging) swings up on every test seed with ``upright_std_rad <= 0.1``; ``inf``
  if no policy within the trial budget does.  Worst seed.  Target: < 90 s.
* ``pilco_train_wall_s`` -- wall-clock seconds of a whole run (model fits, policy searches, trials and the
  test episodes), single-threaded torch.  Worst seed.  Target: < 900 s on the project's 2-core machine.
* ``pilco_train_cpu_s`` -- CPU seconds of a whole run, worst seed (the wall time also counts waiting for a
  machine that other jobs keep busy).
* ``pilco_final_upright_std_rad`` -- the last policy's worst test-seed error, worst run.
* ``..._seed<k>`` -- the same per seed, and ``pilco_trials_seed<k>`` (trials run, the random one included).

The runs are saved to ``runs/bench-pilco/seed<k>`` for inspection; they are always rerun, since their wall
time is the measurement.
"""

from __future__ import annotations

import dataclasses

import torch

from softpend.pilco.loop import PilcoConfig, run_pilco

ROOT = "runs/bench-pilco"
#: Seeds of the benchmark runs.
SEEDS = (0, 1, 2)


def bench_pilco() -> dict[str, float]:
    """The "pilco" benchmark group (see the module docstring)."""
    torch.set_num_threads(1)
    out: dict[str, float] = {}
    for seed in SEEDS:
        result = run_pilco(dataclasses.replace(PilcoConfig(), seed=seed), progress=True)
        result.save(f"{ROOT}/seed{seed}")
        out[f"pilco_real_s_to_balance_seed{seed}"] = result.real_seconds_to_balance
        out[f"pilco_train_wall_s_seed{seed}"] = result.train_wall_s
        out[f"pilco_train_cpu_s_seed{seed}"] = result.train_cpu_s
        out[f"pilco_trials_seed{seed}"] = float(len(result.records))
        out[f"pilco_final_upright_std_rad_seed{seed}"] = result.records[-1].eval_upright_std_rad
    for key in ("pilco_real_s_to_balance", "pilco_train_wall_s", "pilco_train_cpu_s", "pilco_final_upright_std_rad"):
        out[key] = max(out[f"{key}_seed{seed}"] for seed in SEEDS)
    return out

"""``softpend bench --only pilco``: real plant seconds PILCO needs to balance the soft rod, and its compute.

The book's :class:`~softpend.pilco.loop.PilcoConfig` (``book/hparams/pilco.yml``, the project's soft rod) runs
once per seed of :data:`SEEDS`; the targets below hold for *every* seed, so the headline figures are the worst seed's:

* ``pilco_real_s_to_balance`` -- training plant seconds (random trial plus policy trials) up to the first
  policy whose test on the true plant (shared :func:`softpend.evaluation.evaluate_controller`, three
  start-noise seeds, ``eval_duration_s`` = 10 s from hanging) swings up on every test seed with
  ``upright_std_rad <= 0.1``; ``inf`` if no policy within the trial budget does.  Worst seed.  Target: < 90 s.
* ``pilco_train_wall_s`` -- wall-clock seconds of a whole run (model fits, policy searches, trials and the
  test episodes), single-threaded torch.  Worst seed.  Target: < 900 s on the project's 2-core machine.
* ``pilco_train_cpu_s`` -- CPU seconds of a whole run, worst seed (the wall time also counts waiting for a
  machine that other jobs keep busy).
* ``pilco_final_upright_std_rad`` -- the last policy's worst test-seed error, worst run.
* ``..._seed<k>`` -- the same per seed, and ``pilco_trials_seed<k>`` (trials run, the random one included).

The runs are saved to ``runs/bench-pilco/seed<k>`` for inspection; they are always rerun, since their wall
time is the measurement.

Ten seeds, on fresh starts (:data:`TEN_SEEDS`, the runs of ``runs/pilco-book``: reused when present, run
otherwise; their final policies measured on :data:`softpend.study.presets.REPORT_SEEDS`):

* ``seeds_balanced_pilco`` -- runs whose final policy balances >= 90 % of the fresh starts (upright std
  <= 0.1 rad);
* ``pilco_seeds_within_30s`` -- runs that also balanced their own test starts within 30 plant seconds;
* ``pilco_real_s_to_balance`` over those runs as a median with a bootstrap interval
  (``pilco_ten_real_s_to_balance``, ``_low``, ``_high``), and the slowest run's CPU seconds
  (``pilco_ten_max_train_cpu_s``; target: under 600 s of one core).

``softpend bench --only pilco_search`` (:func:`bench_pilco_search`): one policy-search objective and its gradient
at the book's sizes (200 GP points of the ``tip_bend`` state, 50 basis functions, 100 predicted steps, the
tip-rate cost and exploration), eager and through ``torch.compile``, on one thread, alternately in one process:

* ``pilco_search_objective_ms_eager``, ``pilco_search_objective_ms_compiled`` -- CPU milliseconds per objective
  and gradient (median of the repeats);
* ``pilco_search_compiled_speedup`` -- their ratio;
* ``pilco_search_compile_s`` -- CPU seconds of the first compiled call (the compilation, or loading it from the
  on-disk cache);
* ``pilco_search_objective_rel_difference``, ``pilco_search_gradient_rel_difference`` -- how far the compiled
  objective and gradient are from the eager ones (relative).
"""

from __future__ import annotations

import dataclasses

import torch

from softpend.pilco.loop import run_pilco
from softpend.study.presets import PILCO
from softpend.torch_threads import one_torch_thread

ROOT = "runs/bench-pilco"
#: Seeds of the benchmark runs.
SEEDS = (0, 1, 2)
#: Seeds of the ten-seed figures.
TEN_SEEDS = tuple(range(10))


def bench_pilco() -> dict[str, float]:
    """The "pilco" benchmark group (see the module docstring)."""
    torch.set_num_threads(1)
    out: dict[str, float] = {}
    for seed in SEEDS:
        result = run_pilco(dataclasses.replace(PILCO, seed=seed), progress=True)
        result.save(f"{ROOT}/seed{seed}")
        out[f"pilco_real_s_to_balance_seed{seed}"] = result.real_seconds_to_balance
        out[f"pilco_train_wall_s_seed{seed}"] = result.train_wall_s
        out[f"pilco_train_cpu_s_seed{seed}"] = result.train_cpu_s
        out[f"pilco_trials_seed{seed}"] = float(len(result.records))
        out[f"pilco_final_upright_std_rad_seed{seed}"] = result.records[-1].eval_upright_std_rad
    for key in ("pilco_real_s_to_balance", "pilco_train_wall_s", "pilco_train_cpu_s", "pilco_final_upright_std_rad"):
        out[key] = max(out[f"{key}_seed{seed}"] for seed in SEEDS)
    out.update(ten_seed_figures())
    return out


def ten_seed_figures(seeds: tuple[int, ...] = TEN_SEEDS) -> dict[str, float]:
    """The ten-seed PILCO figures of the module docstring."""
    from softpend.study.fresh_starts import headline_figures, pilco_fresh_start_rows, seed_rows
    from softpend.study.head_to_head import pilco_runs
    from softpend.study.presets import PILCO_BOOK

    results = pilco_runs(PILCO, seeds, PILCO_BOOK.runs_root, progress=True)
    figures = headline_figures(seed_rows({}, pilco_fresh_start_rows(results), results))
    out = {key: figures[key] for key in ("seeds_pilco", "seeds_balanced_pilco", "pilco_seeds_within_30s")}
    out["pilco_ten_real_s_to_balance"] = figures["pilco_real_s_to_balance"]
    for end in ("low", "high"):
        out[f"pilco_ten_real_s_to_balance_{end}"] = figures.get(f"pilco_real_s_to_balance_{end}", float("nan"))
    out["pilco_ten_max_train_cpu_s"] = max(result.train_cpu_s for result in results)
    return out


def bench_pilco_search(repeats: int = 5) -> dict[str, float]:
    """The "pilco_search" benchmark group (see the module docstring).  The GP is fitted to a random walk of the
    book's state: the cost of a search depends on the sizes, not on the data."""
    import time

    import numpy as np

    from softpend.pilco.gp import MultiOutputGP
    from softpend.pilco.loop import DTYPE, _initial_distribution, _random_policy
    from softpend.pilco.propagation import Propagator, state_spec

    with one_torch_thread():
        config = PILCO
        spec = state_spec(config.state)
        rng = np.random.default_rng(0)
        n = config.max_gp_points
        states = np.cumsum(rng.normal(0.0, 0.3, (n + 1, spec.dim)), axis=0)
        states[:, spec.angle_indices] += np.pi
        torque_nm = rng.uniform(-1.0, 1.0, n) * config.task.torque_limit_nm
        inputs = np.hstack([spec.model_inputs(states[:-1]), torque_nm[:, None]])
        gp = MultiOutputGP(inputs, states[1:] - states[:-1])
        gp.fit(20)
        policy = _random_policy(
            spec,
            states,
            inputs[:, :-1],
            config.n_basis,
            config.task.torque_limit_nm,
            np.random.default_rng(1),
            config.restart_target_std,
        )
        m0, s0 = _initial_distribution(spec, config.initial_std)
        vector = policy.get_vector()

        def objective(propagator: Propagator) -> tuple[float, np.ndarray, float]:
            start = time.process_time()
            leaf = torch.tensor(vector, dtype=DTYPE, requires_grad=True)
            policy.set_vector(leaf, requires_grad=True)
            total = propagator.rollout(m0, s0, config.n_prediction_steps)[3]
            (grad,) = torch.autograd.grad(total, leaf)
            return float(total.detach()), grad.numpy().copy(), time.process_time() - start

        propagators = {
            compiled: Propagator(
                spec,
                gp,
                policy,
                config.task.rod.length_m,
                config.cost_width_m,
                config.cost_rate_width_rad_s,
                config.cost_exploration,
                compiled=compiled,
            )
            for compiled in (False, True)
        }
        eager_value, eager_grad, _ = objective(propagators[False])
        compiled_value, compiled_grad, compile_s = objective(propagators[True])
        times: dict[bool, list[float]] = {False: [], True: []}
        for _ in range(repeats):
            for compiled, propagator in propagators.items():
                times[compiled].append(objective(propagator)[2])
    eager_ms, compiled_ms = (1000.0 * float(np.median(times[c])) for c in (False, True))
    return {
        "pilco_search_objective_ms_eager": eager_ms,
        "pilco_search_objective_ms_compiled": compiled_ms,
        "pilco_search_compiled_speedup": eager_ms / compiled_ms,
        "pilco_search_compile_s": compile_s,
        "pilco_search_objective_rel_difference": abs(compiled_value - eager_value) / abs(eager_value),
        "pilco_search_gradient_rel_difference": float(
            np.max(np.abs(compiled_grad - eager_grad)) / np.max(np.abs(eager_grad))
        ),
    }

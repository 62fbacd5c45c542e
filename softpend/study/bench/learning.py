"""Learning benchmarks: DQN training speed and the book's DQN and DQN-MBPO ten-seed figures and CPU time (``softpend
bench --only rl``); PILCO's plant seconds to balance and compute of the book's runs (``--only pilco``); its policy
search eager vs compiled (``--only pilco_search``)."""

from __future__ import annotations

import dataclasses
import math
import tempfile
from typing import Any, Sequence

import torch

from softpend.pilco.loop import run_pilco
from softpend.study.presets import DQN, PILCO
from softpend.torch_threads import one_torch_thread


def dqn_train_steps_per_s(episodes: int = 10) -> float:
    """Agent steps per second of DQN training between the ends of the first and the last of ``1 + episodes``."""
    from softpend.rl.dqn import train_dqn

    rare = dict(eval_every_episodes=10_000, checkpoint_every_episodes=10_000)
    config = dataclasses.replace(DQN, learning_starts=0, **rare, eval_seeds=(0,), eval_duration_s=0.1)
    with tempfile.TemporaryDirectory() as tmp:
        _, log = train_dqn(config, seed=0, episodes=1 + episodes, run_dir=tmp, progress=False)
    elapsed = log.episodes[-1]["wall_s"] - log.episodes[0]["wall_s"]
    return episodes * config.episode_agent_steps / elapsed


def training_cpu_s(log) -> float:
    """CPU seconds a run spent training, final evaluation included (``nan`` for a run without ``cpu_s``)."""
    values = [row.get("cpu_s", math.nan) for row in log.episodes + log.evaluations]
    return float(max(values)) if values and all(math.isfinite(v) for v in values) else math.nan


def bench_rl() -> dict[str, float]:
    """The ``rl`` benchmark group (see the module docstring)."""
    from softpend.study.fresh_starts import converged_fresh_start_rows, headline_figures, rl_fresh_start_rows, seed_rows
    from softpend.study.presets import RL_BOOK
    from softpend.study.rl_runs import METHOD_NAMES, figure_runs

    steps_per_s = dqn_train_steps_per_s()
    runs = figure_runs(RL_BOOK.episodes_dqn, RL_BOOK.episodes_mbpo, RL_BOOK.seeds, RL_BOOK.runs_root, progress=True)
    logs: dict[str, Sequence[Any]] = {"dqn": runs[METHOD_NAMES["dqn"]], "mbpo": runs[METHOD_NAMES["mbpo"]]}
    fresh = rl_fresh_start_rows(RL_BOOK.runs_root, RL_BOOK.seeds, which=("final",))
    converged = converged_fresh_start_rows(RL_BOOK.runs_root, RL_BOOK.seeds)
    cpu_s = sum(training_cpu_s(log) for group in logs.values() for log in group)
    balanced = {algo: sum(r["run_balances"] for r in converged if r["method"] == METHOD_NAMES[algo]) for algo in logs}
    return {
        "dqn_train_steps_per_s": steps_per_s,
        **headline_figures(seed_rows(logs, fresh)),
        **{f"seeds_balanced_{algo}_converged_plant": float(count) for algo, count in balanced.items()},
        "full_profile_train_cpu_s": cpu_s,
        "full_profile_train_2core_s": cpu_s / 2.0,
    }


ROOT = "runs/bench-pilco"
SEEDS = (0, 1, 2)
TEN_SEEDS = tuple(range(10))


def bench_pilco() -> dict[str, float]:
    """The ``pilco`` benchmark group: runs saved to ``runs/bench-pilco/seed<k>``, always rerun."""
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
    """Balanced seeds and plant seconds to balance of the book's ten PILCO runs on fresh starts."""
    from softpend.study.fresh_starts import headline_figures, pilco_fresh_start_rows, seed_rows
    from softpend.study.head_to_head import pilco_runs
    from softpend.study.presets import PILCO_BOOK

    results = pilco_runs(PILCO, seeds, PILCO_BOOK.runs_root, progress=True)
    figures = headline_figures(seed_rows({}, pilco_fresh_start_rows(results), results))
    out = {key: figures[key] for key in ("seeds_pilco", "seeds_balanced_pilco", "pilco_seeds_within_30s")}
    for end in ("", "_low", "_high"):  # the median, and its interval where there are two runs or more
        out[f"pilco_ten_real_s_to_balance{end}"] = figures.get(f"pilco_real_s_to_balance{end}", float("nan"))
    out["pilco_ten_max_train_cpu_s"] = max(result.train_cpu_s for result in results)
    return out


def bench_pilco_search(repeats: int = 5) -> dict[str, float]:
    """CPU milliseconds of one policy-search objective and gradient (GP fitted to a random walk), eager and compiled,
    and how far apart their results are."""
    import time

    import numpy as np

    from softpend.pilco.gp import MultiOutputGP
    from softpend.pilco.loop import DTYPE, Pilco
    from softpend.pilco.propagation import Propagator, state_spec

    with one_torch_thread():
        config, spec, n = PILCO, state_spec(PILCO.state), PILCO.gp.max_points
        rng, rng1 = np.random.default_rng(0), np.random.default_rng(1)
        states = np.cumsum(rng.normal(0.0, 0.3, (n + 1, spec.dim)), axis=0)
        states[:, spec.angle_indices] += np.pi
        torque_nm = rng.uniform(-1.0, 1.0, n) * config.task.torque_limit_nm
        inputs = np.hstack([spec.model_inputs(states[:-1]), torque_nm[:, None]])
        gp = MultiOutputGP(inputs, states[1:] - states[:-1])
        gp.fit(20)
        pilco = Pilco(config)  # its first policy drawn from this random walk
        pilco.real_states, pilco.inputs = [states], [inputs]
        policy, m0, s0 = pilco._random_policy(rng1, config.optimiser.restart_target_std), pilco.m0, pilco.s0
        vector = policy.get_vector()

        def objective(propagator: Propagator) -> tuple[float, np.ndarray, float]:
            start = time.process_time()
            leaf = torch.tensor(vector, dtype=DTYPE, requires_grad=True)
            policy.set_vector(leaf, requires_grad=True)
            total = propagator.rollout(m0, s0, config.n_prediction_steps)[3]
            (grad,) = torch.autograd.grad(total, leaf)
            return float(total.detach()), grad.numpy().copy(), time.process_time() - start

        cost = (config.task.rod.length_m, config.cost.width_m, config.cost.rate_width_rad_s, config.cost.exploration)
        propagators = {compiled: Propagator(spec, gp, policy, *cost, compiled=compiled) for compiled in (False, True)}
        eager_value, eager_grad, _ = objective(propagators[False])
        compiled_value, compiled_grad, compile_s = objective(propagators[True])
        times: dict[bool, list[float]] = {False: [], True: []}
        for _ in range(repeats):
            for compiled, propagator in propagators.items():
                times[compiled].append(objective(propagator)[2])
    eager_ms, compiled_ms = (1000.0 * float(np.median(times[c])) for c in (False, True))
    figures = {"pilco_search_objective_ms_eager": eager_ms, "pilco_search_objective_ms_compiled": compiled_ms}
    figures |= {"pilco_search_compiled_speedup": eager_ms / compiled_ms, "pilco_search_compile_s": compile_s}
    value = abs(compiled_value - eager_value) / abs(eager_value)
    gradient = float(np.abs(compiled_grad - eager_grad).max() / np.abs(eager_grad).max())
    return figures | {"pilco_search_objective_rel_difference": value, "pilco_search_gradient_rel_difference": gradient}

"""Plant and environment speed and accuracy (``softpend bench --only plant``): Exudyn environment and solver, batched
chain, vector environment, hub-angle errors against a converged run and, where installed, the chain in MuJoCo; the
beam plant's speed and accuracy (``--only beam``)."""

from __future__ import annotations

import importlib.util
import math
import sys
import time
import types
from typing import Any

import gymnasium as gym
import numpy as np

from softpend.fidelity.validation import measured_bending_frequencies, static_tip_sag
from softpend.plant.params import RodParams
from softpend.plant.prb import PRBPlant
from softpend.study.bench import best_times, mujoco_chain
from softpend.study.simulators import hub_error_reference, hub_errors_rad
from softpend.torch_threads import one_torch_thread

N_STEPS = 4000


def env_steps_per_s(n_links: int = 4, n_steps: int = N_STEPS, plant: str = "prb", legacy: bool = False) -> float:
    """Steps per second through the Gymnasium API under seeded random actions (``legacy``: :func:`make_legacy`)."""
    import softpend  # noqa: F401

    env = gym.make("softpend/SoftPendulum-v0", params=RodParams(n_links=n_links), plant=plant)
    if legacy:
        make_legacy(env)
    actions = np.random.default_rng(0).uniform(-1, 1, size=(n_steps, 1)).astype(np.float32)
    env.reset(seed=0)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return n_steps / (time.perf_counter() - start)


def _solver_steps_per_s(n_links: int, n_steps: int = N_STEPS) -> float:
    """Steps per second of the bare Exudyn loop: set the joint torque, advance."""
    plant = PRBPlant(RodParams(n_links=n_links))
    plant.reset(*plant.hanging_state())
    chain = plant._chain
    torques = np.random.default_rng(0).uniform(-1, 1, size=n_steps) * plant.params.torque_limit_nm
    forces = np.zeros(plant.n_coordinates)
    start = time.perf_counter()
    for torque in torques:
        forces[0] = torque
        chain.set_joint_forces(forces)
        chain.advance()
    return n_steps / (time.perf_counter() - start)


def _legacy_advance(self) -> None:
    import exudyn as exu

    from softpend.plant.exudyn_adapter import SolverFailure

    settings, mbs = self._settings, self._mbs
    settings.timeIntegration.startTime = self.time_s
    settings.timeIntegration.endTime = self.time_s + self.dt_s
    self._solver.InitializeSolverInitialConditions(mbs, settings)
    try:
        ok = self._solver.SolveSteps(mbs, settings)
    except exu.ExudynError:
        ok = False
    data = mbs.systemData
    state = data.GetSystemState()
    if not ok or not math.isfinite(float(np.sum(state[0])) + float(np.sum(state[1]))):
        raise SolverFailure(f"Exudyn implicit solver failed at t = {self.time_s:.4f} s")
    self._q, self._q_t = state[0], state[1]
    data.SetSystemState(systemStateList=state, configuration=exu.ConfigurationType.Initial)
    data.SetODE2Coordinates_tt(coordinates=data.GetODE2Coordinates_tt(), configuration=exu.ConfigurationType.Initial)
    self.time_s += self.dt_s


def _legacy_observe(self):
    return self.observation_from_state(self._chain._q.tolist(), self._chain._q_t.tolist())


def make_legacy(env) -> None:
    """Give ``env`` (PRB plant) the baseline step path of ``env_steps_per_s_n4_speedup`` (more Python-C++ crossings)."""
    plant = env.unwrapped.plant
    plant._chain.advance = types.MethodType(_legacy_advance, plant._chain)
    plant.observe = types.MethodType(_legacy_observe, plant)


#: Rods of the batched chain's timings, environments of the vector environment's.
BATCH_SIZE, NUM_ENVS = 4096, 1024


def batched_rod_steps_per_s(
    n_links: int, n_steps: int = 6, repeats: int = 3, dtype_name: str = "float64", **chain_options: Any
) -> tuple[float, float]:
    """Rod-steps per wall-clock and CPU second of the batched chain on one torch thread (best of ``repeats``)."""
    from softpend.plant.batched import BatchedPRBChain

    with one_torch_thread() as torch:
        dtype = getattr(torch, dtype_name)
        chain = BatchedPRBChain(RodParams(n_links=n_links), batch_size=BATCH_SIZE, dtype=dtype, **chain_options)
        generator = torch.Generator().manual_seed(0)
        torques = ((torch.rand(n_steps, BATCH_SIZE, generator=generator, dtype=torch.float64) * 2 - 1) * 0.06).to(dtype)
        with torch.no_grad():
            q, qd = chain.hanging_state()
            q, qd = chain.step(q, qd, torques[0])  # warm-up (and compilation)

            def run() -> None:
                nonlocal q, qd
                for torque in torques:
                    q, qd = chain.step(q, qd, torque)

            best, best_cpu = best_times(run, repeats)
            if not bool(torch.isfinite(q).all()):
                raise RuntimeError(f"the batched chain diverged in the benchmark ({chain.integrator}, n = {n_links})")
    return BATCH_SIZE * n_steps / best, BATCH_SIZE * n_steps / max(best_cpu, 1e-9)


def vector_env_steps_per_s(n_links: int = 4, n_steps: int = 40, **env_options: Any) -> tuple[float, float]:
    """Steps per wall-clock and CPU second of the vector environment on one torch thread (best of 3)."""
    from softpend.envs.vector import SoftPendulumVectorEnv

    with one_torch_thread():
        env = SoftPendulumVectorEnv(num_envs=NUM_ENVS, params=RodParams(n_links=n_links), **env_options)
        actions = np.random.default_rng(0).uniform(-1, 1, (n_steps, NUM_ENVS, 1)).astype(np.float32)
        env.reset(seed=0)
        env.step(actions[0])
        best, best_cpu = best_times(lambda: [env.step(action) for action in actions], 3)
    return NUM_ENVS * n_steps / best, NUM_ENVS * n_steps / max(best_cpu, 1e-9)


def bench_plant() -> dict[str, float]:
    """The ``plant`` benchmark group (see the module docstring)."""
    env4 = max(env_steps_per_s(4) for _ in range(2))
    solver4 = max(_solver_steps_per_s(4) for _ in range(2))
    env10 = env_steps_per_s(10)
    paths = {False: 0.0, True: 0.0}  # today's step path and the legacy one, interleaved
    for _ in range(3):
        for legacy in paths:
            paths[legacy] = max(paths[legacy], env_steps_per_s(4, legacy=legacy))
    fast: dict[str, Any] = {"integrator": "rosenbrock", "compiled": True}
    batched = {n: batched_rod_steps_per_s(n, dtype_name="float32", **fast) for n in (4, 10)}
    batched64 = {n: batched_rod_steps_per_s(n, **fast)[0] for n in (4, 10)}
    rk4 = {4: batched_rod_steps_per_s(4)[0], 10: batched_rod_steps_per_s(10, n_steps=2, repeats=2)[0]}
    vector4, vector4_cpu = vector_env_steps_per_s(4, **fast)
    vector4_default, _ = vector_env_steps_per_s(4)
    figures = {
        "env_steps_per_s_n4": env4,
        "env_steps_per_s_n10": env10,
        "solver_steps_per_s_n4": solver4,
        "realtime_factor_n4": env4 * 0.01,  # a control step of 0.01 s
        "wrapper_overhead_fraction_n4": solver4 / env4 - 1.0,
        "env_steps_per_s_n4_legacy_path": paths[True],
        "env_steps_per_s_n4_speedup": paths[False] / paths[True],
        **{f"batched_rod_steps_per_s_n{n}": rate for n, (rate, _) in batched.items()},
        **{f"batched_rod_steps_per_cpu_s_n{n}": cpu for n, (_, cpu) in batched.items()},
        **{f"batched_rod_steps_per_s_n{n}_float64": rate for n, rate in batched64.items()},
        **{f"batched_rk4_rod_steps_per_s_n{n}": rate for n, rate in rk4.items()},
        "vector_env_steps_per_s_n4": vector4,
        "vector_env_steps_per_cpu_s_n4": vector4_cpu,
        "vector_env_steps_per_s_n4_default": vector4_default,
    }
    references = {n: hub_error_reference(n, duration_s=d) for n, d in ((4, 5.0), (10, 1.0))}
    for n, d in ((4, 5.0), (10, 1.0)):
        figures.update(hub_errors_rad(n, duration_s=d, reference=references[n]))
    if importlib.util.find_spec("mujoco") is not None:
        return figures | mujoco_chain.bench_figures(figures, references)
    print("[bench] plant: MuJoCo is not installed (pip install softpend[bench]): no mujoco_* figures", file=sys.stderr)
    return figures


def bench_beam() -> dict[str, float]:
    """Beam environment step rate, real-time factor, frequency and static-sag errors against Euler-Bernoulli [%]."""
    steps = max(env_steps_per_s(n_steps=2000, plant="beam") for _ in range(2))
    freqs = measured_bending_frequencies("beam")
    sag = static_tip_sag("beam", RodParams(stiffness_scale=100.0))
    return {
        "beam_env_steps_per_s": steps,
        "beam_realtime_factor": steps * 0.01,
        "beam_first_freq_error_pct": abs(freqs["f1_error_pct"]),
        "beam_second_freq_error_pct": abs(freqs["f2_error_pct"]),
        "beam_static_sag_error_pct": abs(sag["error_pct"]),
    }

"""Plant and environment speed (``softpend bench --only plant``).

* ``env_steps_per_s_n4``/``_n10``, ``solver_steps_per_s_n4``: the single Exudyn environment and its bare solver loop;
  ``env_steps_per_s_n4_speedup``: today's step path over the legacy one (:func:`make_legacy`), same run.
* ``batched_rod_steps_per_s_n4``/``_n10``: the batched torch chain, 4096 rods, one torch thread, in its fast
  configuration: the Rosenbrock integrator (two sub-steps), compiled (``torch.compile``), float32;
  ``..._float64``: the same in float64; ``batched_rk4_rod_steps_per_s_n*``: the chain's defaults (RK4 at its
  stability limit, eager, float64), the configuration of the converged-plant evaluations.
* ``vector_env_steps_per_s_n4``: the vector environment, 1024 rods, observation and reward included, with the
  Rosenbrock integrator compiled; ``..._default``: with the environment's defaults (RK4, eager).
* ``*_per_cpu_s_*``: the same counts per CPU second of the benchmark process (on a shared machine the
  wall-clock rates fall with the other processes' load; these much less).
* ``batched_chain_hub_error_rad_n*`` (RK4), ``batched_rosenbrock_hub_error_rad_n*`` (the fast configuration)
  beside ``exudyn_default_hub_error_rad_n*``: largest hub-angle error against the Exudyn plant with 200
  sub-steps (5 s of random torque at n = 4, 1 s at n = 10).
* ``mujoco_*`` (only where ``import mujoco`` works, ``pip install softpend[bench]``; otherwise absent, and one line
  on stderr says so): the same chain in MuJoCo (:mod:`softpend.study.bench.mujoco_chain`), one rod stepped from
  Python per control step: ``mujoco_rk4_5ms_steps_per_s_n4``, ``mujoco_implicitfast_2p5ms_steps_per_s_n4``; at
  n = 10, where those steps diverge (``mujoco_rk4_5ms_diverges_n10``, ``mujoco_implicitfast_2p5ms_diverges_n10``:
  1 if so), ``mujoco_rk4_stable_steps_per_s_n10`` (RK4 with the batched chain's sub-step count,
  ``mujoco_rk4_stable_substeps_n10``) and ``mujoco_implicitfast_0p5ms_steps_per_s_n10``; their
  ``*_hub_error_rad_n*`` against the same Exudyn reference, beside ``mujoco_rk4_0p25ms_hub_error_rad_n*`` (a
  converged MuJoCo run: the check that the two models are the same chain);
  ``mujoco_rollout_rk4_5ms_rod_steps_per_s_n4``: ``mujoco.rollout`` over 4096 rods on one thread.
* ratios, same run: ``exudyn_env_over_mujoco_rk4_n4`` and ``exudyn_solver_over_mujoco_rk4_n4`` (the single
  Exudyn environment's and its bare solver loop's steps/s over MuJoCo RK4's), ``batched_over_mujoco_rk4_n4``/``_n10``
  (the batched chain's fast configuration, rod-steps/s, over MuJoCo RK4's steps/s), ``batched_rk4_over_mujoco_rk4_n*``
  (the batched chain's RK4, the same integrator and step as MuJoCo's), ``batched_over_mujoco_rollout_n4`` and
  ``batched_rk4_over_mujoco_rollout_n4`` (over ``mujoco.rollout``: batch against batch).
"""

from __future__ import annotations

import math
import sys
import time
import types
from typing import Any

import gymnasium as gym
import numpy as np

from softpend.plant.params import RodParams
from softpend.plant.prb import PRBPlant
from softpend.study.bench import mujoco_chain
from softpend.study.simulators import hub_error_reference, hub_errors_rad
from softpend.torch_threads import one_torch_thread

N_STEPS = 4000


def env_steps_per_s(n_links: int = 4, n_steps: int = N_STEPS, plant: str = "prb") -> float:
    """Steps per second through the Gymnasium API (``gym.make``, random actions from a seeded generator)."""
    import softpend  # noqa: F401  (registers the environments)

    env = gym.make("softpend/SoftPendulum-v0", params=RodParams(n_links=n_links), plant=plant)
    return _timed_steps_per_s(env, np.random.default_rng(0).uniform(-1, 1, size=(n_steps, 1)).astype(np.float32))


def _timed_steps_per_s(env: gym.Env, actions: np.ndarray) -> float:
    """Steps per wall-clock second of ``env`` (reset with seed 0) through ``actions``, reset when an episode ends."""
    env.reset(seed=0)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return len(actions) / (time.perf_counter() - start)


def _solver_steps_per_s(n_links: int, n_steps: int = N_STEPS) -> float:
    """The bare Exudyn loop: set the joint torque, advance one control step, nothing else."""
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


# ---------------------------------------------------------------------------------------------------------
# The baseline of ``env_steps_per_s_n4_speedup``: the single environment's step path with more Python-C++
# crossings (settings and system data fetched through pybind11 at every step, the finiteness check through
# np.sum, the observation converting the state arrays with ``tolist`` once more).  Same numbers.


def _legacy_advance(self) -> None:
    import exudyn as exu

    from softpend.plant.exudyn_adapter import SolverFailure

    settings = self._settings
    mbs = self._mbs
    settings.timeIntegration.startTime = self.time_s
    settings.timeIntegration.endTime = self.time_s + self.dt_s
    self._solver.InitializeSolverInitialConditions(mbs, settings)
    try:
        ok = self._solver.SolveSteps(mbs, settings)
    except exu.ExudynError as exc:
        raise SolverFailure(
            f"Exudyn implicit solver failed at t = {self.time_s:.4f} s: {' '.join(str(exc).split())}"
        ) from exc
    data = mbs.systemData
    state = data.GetSystemState()
    if not ok:
        raise SolverFailure(f"Exudyn implicit solver failed at t = {self.time_s:.4f} s")
    if not math.isfinite(float(np.sum(state[0])) + float(np.sum(state[1]))):
        raise SolverFailure(f"non-finite state at t = {self.time_s + self.dt_s:.4f} s")
    self._q, self._q_t = state[0], state[1]
    data.SetSystemState(systemStateList=state, configuration=exu.ConfigurationType.Initial)
    data.SetODE2Coordinates_tt(coordinates=data.GetODE2Coordinates_tt(), configuration=exu.ConfigurationType.Initial)
    self.time_s += self.dt_s


def _legacy_observe(self):
    q, qd = self._chain.get_state_views()
    return self.observation_from_state(q.tolist(), qd.tolist())


def make_legacy(env) -> None:
    """Give ``env`` (a ``gym.make`` environment on the PRB plant) the baseline step path above
    (``tests/test_bench_plant.py`` holds both paths to identical numbers)."""
    plant = env.unwrapped.plant
    plant._chain.advance = types.MethodType(_legacy_advance, plant._chain)
    plant.observe = types.MethodType(_legacy_observe, plant)


def env_steps_per_s_paths(n_links: int = 4, n_steps: int = N_STEPS, repeats: int = 3) -> tuple[float, float]:
    """Steps per second of the single environment through today's step path and the legacy one, interleaved
    ``repeats`` times (best of each kept), so that both see the same machine load."""
    import softpend  # noqa: F401  (registers the environments)

    actions = np.random.default_rng(0).uniform(-1, 1, size=(n_steps, 1)).astype(np.float32)
    best = {"new": 0.0, "legacy": 0.0}
    for _ in range(repeats):
        for path in ("new", "legacy"):
            env = gym.make("softpend/SoftPendulum-v0", params=RodParams(n_links=n_links))
            if path == "legacy":
                make_legacy(env)
            best[path] = max(best[path], _timed_steps_per_s(env, actions))
    return best["new"], best["legacy"]


# ---------------------------------------------------------------------------------------------------------
# The batched torch chain and the vector environment


def batched_rod_steps_per_s(
    n_links: int,
    batch_size: int = 4096,
    n_steps: int = 6,
    repeats: int = 3,
    integrator: str = "rk4",
    compiled: bool = False,
    dtype_name: str = "float64",
) -> tuple[float, float]:
    """Rod-steps of 0.01 s per second of the batched chain (default sub-steps of ``integrator``, one torch thread,
    random torques, no gradients): ``batch_size * n_steps`` over the best of ``repeats`` timed runs, per
    wall-clock second and per CPU second of this process (the latter less sensitive to other work on the
    machine).  A compiled chain is compiled by an untimed first step."""
    from softpend.plant.batched import BatchedPRBChain

    with one_torch_thread() as torch:
        dtype = getattr(torch, dtype_name)
        chain = BatchedPRBChain(
            RodParams(n_links=n_links), batch_size=batch_size, integrator=integrator, compiled=compiled, dtype=dtype
        )
        generator = torch.Generator().manual_seed(0)
        torques = ((torch.rand(n_steps, batch_size, generator=generator, dtype=torch.float64) * 2 - 1) * 0.06).to(dtype)
        best = best_cpu = math.inf
        with torch.no_grad():
            q, qd = chain.hanging_state()
            q, qd = chain.step(q, qd, torques[0])  # warm-up (and compilation)
            for _ in range(repeats):
                start, start_cpu = time.perf_counter(), time.process_time()
                for torque in torques:
                    q, qd = chain.step(q, qd, torque)
                best = min(best, time.perf_counter() - start)
                best_cpu = min(best_cpu, time.process_time() - start_cpu)
            if not bool(torch.isfinite(q).all()):
                raise RuntimeError(f"the batched chain diverged in the benchmark ({integrator}, n = {n_links})")
    return batch_size * n_steps / best, batch_size * n_steps / max(best_cpu, 1e-9)


def vector_env_steps_per_s(
    n_links: int = 4,
    num_envs: int = 1024,
    n_steps: int = 40,
    repeats: int = 3,
    integrator: str = "rk4",
    compiled: bool = False,
) -> tuple[float, float]:
    """Environment steps per second of :class:`~softpend.envs.vector.SoftPendulumVectorEnv` (observation and
    reward included, random actions, one torch thread): ``num_envs * n_steps`` over the best timed run, per
    wall-clock second and per CPU second of this process."""
    from softpend.envs.vector import SoftPendulumVectorEnv

    with one_torch_thread():
        env = SoftPendulumVectorEnv(
            num_envs=num_envs, params=RodParams(n_links=n_links), integrator=integrator, compiled=compiled
        )
        actions = np.random.default_rng(0).uniform(-1, 1, (n_steps, num_envs, 1)).astype(np.float32)
        env.reset(seed=0)
        env.step(actions[0])
        best = best_cpu = math.inf
        for _ in range(repeats):
            start, start_cpu = time.perf_counter(), time.process_time()
            for action in actions:
                env.step(action)
            best = min(best, time.perf_counter() - start)
            best_cpu = min(best_cpu, time.process_time() - start_cpu)
    return num_envs * n_steps / best, num_envs * n_steps / max(best_cpu, 1e-9)


def bench_plant() -> dict[str, float]:
    """Env and bare-solver step rates at n = 4 and n = 10 (random actions, dt = 0.01 s, 2 sub-steps); the
    speed-up of the single environment's step over its legacy path; the batched chain's and the vector
    environment's rates and the batched chain's accuracy beside the default Exudyn plant's.

    The env and solver loops for n = 4 are interleaved twice and the best of each kept, so that the
    wrapper-cost ratio compares like with like on a noisy machine.
    """
    env4 = max(env_steps_per_s(4) for _ in range(2))
    solver4 = max(_solver_steps_per_s(4) for _ in range(2))
    env10 = env_steps_per_s(10)
    new4, legacy4 = env_steps_per_s_paths(4)
    dt_s = 0.01
    fast: dict[str, Any] = {"integrator": "rosenbrock", "compiled": True}
    batched4, batched4_cpu = batched_rod_steps_per_s(4, dtype_name="float32", **fast)
    batched10, batched10_cpu = batched_rod_steps_per_s(10, dtype_name="float32", **fast)
    batched4_64, _ = batched_rod_steps_per_s(4, **fast)
    batched10_64, _ = batched_rod_steps_per_s(10, **fast)
    rk4_4, _ = batched_rod_steps_per_s(4)
    rk4_10, _ = batched_rod_steps_per_s(10, n_steps=2, repeats=2)
    vector4, vector4_cpu = vector_env_steps_per_s(4, **fast)
    vector4_default, _ = vector_env_steps_per_s(4)
    figures = {
        "env_steps_per_s_n4": env4,
        "env_steps_per_s_n10": env10,
        "solver_steps_per_s_n4": solver4,
        "realtime_factor_n4": env4 * dt_s,
        "wrapper_overhead_fraction_n4": solver4 / env4 - 1.0,
        "env_steps_per_s_n4_legacy_path": legacy4,
        "env_steps_per_s_n4_speedup": new4 / legacy4,
        "batched_rod_steps_per_s_n4": batched4,
        "batched_rod_steps_per_cpu_s_n4": batched4_cpu,
        "batched_rod_steps_per_s_n10": batched10,
        "batched_rod_steps_per_cpu_s_n10": batched10_cpu,
        "batched_rod_steps_per_s_n4_float64": batched4_64,
        "batched_rod_steps_per_s_n10_float64": batched10_64,
        "batched_rk4_rod_steps_per_s_n4": rk4_4,
        "batched_rk4_rod_steps_per_s_n10": rk4_10,
        "vector_env_steps_per_s_n4": vector4,
        "vector_env_steps_per_cpu_s_n4": vector4_cpu,
        "vector_env_steps_per_s_n4_default": vector4_default,
    }
    references = {4: hub_error_reference(4, duration_s=5.0), 10: hub_error_reference(10, duration_s=1.0)}
    figures.update(hub_errors_rad(4, duration_s=5.0, reference=references[4]))
    figures.update(hub_errors_rad(10, duration_s=1.0, reference=references[10]))
    if mujoco_chain.mujoco_available():
        figures.update(mujoco_chain.bench_figures(figures, references))
    else:
        print(
            "[bench] plant: MuJoCo is not installed (pip install softpend[bench]): no mujoco_* figures",
            file=sys.stderr,
            flush=True,
        )
    return figures

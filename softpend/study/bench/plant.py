"""Plant and environment speed (``softpend bench --only plant``)."""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np

from softpend.plant.params import RodParams
from softpend.plant.prb import PRBPlant

N_STEPS = 4000


def env_steps_per_s(n_links: int = 4, n_steps: int = N_STEPS, plant: str = "prb") -> float:
    """Steps per second through the Gymnasium API (``gym.make``, random actions from a seeded generator)."""
    import softpend  # noqa: F401  (registers the environments)

    env = gym.make("softpend/SoftPendulum-v0", params=RodParams(n_links=n_links), plant=plant)
    actions = np.random.default_rng(0).uniform(-1, 1, size=(n_steps, 1)).astype(np.float32)
    env.reset(seed=0)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return n_steps / (time.perf_counter() - start)


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


def bench_plant() -> dict[str, float]:
    """Env and bare-solver step rates at n = 4 and n = 10 (random actions, dt = 0.01 s, 2 sub-steps).

    The env and solver loops for n = 4 are interleaved twice and the best of each kept, so that the
    wrapper-cost ratio compares like with like on a noisy machine.
    """
    env4 = max(env_steps_per_s(4) for _ in range(2))
    solver4 = max(_solver_steps_per_s(4) for _ in range(2))
    env10 = env_steps_per_s(10)
    dt_s = 0.01
    return {
        "env_steps_per_s_n4": env4,
        "env_steps_per_s_n10": env10,
        "solver_steps_per_s_n4": solver4,
        "realtime_factor_n4": env4 * dt_s,
        "wrapper_overhead_fraction_n4": solver4 / env4 - 1.0,
    }

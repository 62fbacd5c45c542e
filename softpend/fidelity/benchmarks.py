"""Beam-plant speed and accuracy (``softpend bench --json --only beam``)."""

from __future__ import annotations

import time

import gymnasium as gym
import numpy as np

from ..plant import RodParams
from .validation import measured_bending_frequencies, static_tip_sag

N_STEPS = 2000


def _beam_env_steps_per_s(n_steps: int = N_STEPS) -> float:
    """Environment steps per second on the beam plant (default element count, random actions)."""
    import softpend  # noqa: F401  (registers the environments)

    env = gym.make("softpend/SoftPendulum-v0", plant="beam")
    actions = np.random.default_rng(0).uniform(-1, 1, size=(n_steps, 1)).astype(np.float32)
    env.reset(seed=0)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return n_steps / (time.perf_counter() - start)


def bench_beam() -> dict[str, float]:
    """Beam env step rate (best of two), its real-time factor at dt = 0.01 s, and the validation errors
    of the default beam: first two cantilever frequencies (free-vibration run) and the static sag of a
    stiff (small-deflection) rod, all against Euler-Bernoulli [%]."""
    steps = max(_beam_env_steps_per_s() for _ in range(2))
    freqs = measured_bending_frequencies("beam")
    sag = static_tip_sag("beam", RodParams(stiffness_scale=100.0))
    return {
        "beam_env_steps_per_s": steps,
        "beam_realtime_factor": steps * 0.01,
        "beam_first_freq_error_pct": abs(freqs["f1_error_pct"]),
        "beam_second_freq_error_pct": abs(freqs["f2_error_pct"]),
        "beam_static_sag_error_pct": abs(sag["error_pct"]),
    }

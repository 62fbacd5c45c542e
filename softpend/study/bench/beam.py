"""Beam-plant speed and accuracy (``softpend bench --json --only beam``)."""

from __future__ import annotations

from softpend.fidelity.validation import measured_bending_frequencies, static_tip_sag
from softpend.plant import RodParams
from softpend.study.bench.plant import env_steps_per_s

N_STEPS = 2000


def bench_beam() -> dict[str, float]:
    """Beam environment step rate, real-time factor, frequency and static-sag errors against Euler-Bernoulli [%]."""
    steps = max(env_steps_per_s(n_steps=N_STEPS, plant="beam") for _ in range(2))
    freqs = measured_bending_frequencies("beam")
    sag = static_tip_sag("beam", RodParams(stiffness_scale=100.0))
    return {
        "beam_env_steps_per_s": steps,
        "beam_realtime_factor": steps * 0.01,
        "beam_first_freq_error_pct": abs(freqs["f1_error_pct"]),
        "beam_second_freq_error_pct": abs(freqs["f2_error_pct"]),
        "beam_static_sag_error_pct": abs(sag["error_pct"]),
    }

"""Model fidelity: the continuum-beam plant validated against beam theory, the PRB chain compared with it,
and controllers designed on the PRB plant evaluated on the beam (the project's stand-in for the real rod)."""

from softpend.fidelity.validation import (
    EULER_BERNOULLI_BETA_L,
    FreeVibration,
    cantilever_free_vibration,
    euler_bernoulli_frequencies_hz,
    fit_modal_frequencies_hz,
    measured_bending_frequencies,
    static_tip_sag,
)

__all__ = [
    "EULER_BERNOULLI_BETA_L",
    "FreeVibration",
    "cantilever_free_vibration",
    "euler_bernoulli_frequencies_hz",
    "fit_modal_frequencies_hz",
    "measured_bending_frequencies",
    "static_tip_sag",
]

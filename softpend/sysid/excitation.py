"""Designed excitation: a Schroeder-phased multisine torque program within the torque limit."""

from __future__ import annotations

import math

import numpy as np

from softpend.checks import positive, positive_int

__all__ = ["multisine", "multisine_frequencies_hz"]


def multisine_frequencies_hz(period_s: float, band_hz: tuple[float, float]) -> np.ndarray:
    """The harmonics ``k / period_s`` of the period that lie in ``band_hz`` (inclusive)."""
    positive("period_s", period_s)
    low, high = (float(b) for b in band_hz)
    if not (math.isfinite(low) and math.isfinite(high) and 0 < low <= high):
        raise ValueError(f"band_hz must be (low, high) with 0 < low <= high, got {band_hz!r}")
    k = np.arange(math.ceil(low * period_s - 1e-9), math.floor(high * period_s + 1e-9) + 1)
    if k.size == 0:
        raise ValueError(f"band_hz {band_hz!r} holds no harmonic of 1 / period_s = {1 / period_s:g} Hz")
    return k / period_s


def multisine(
    n_steps: int,
    dt_s: float,
    peak_nm: float,
    band_hz: tuple[float, float] = (0.2, 6.0),
    period_s: float = 5.0,
) -> np.ndarray:
    """``n_steps`` samples (step ``dt_s``) of a multisine of period ``period_s``: equal-amplitude harmonics in
    ``band_hz`` with Schroeder phases ``-pi k (k - 1) / K`` (a low crest factor), peak exactly ``peak_nm``."""
    n_steps = positive_int("n_steps", n_steps)
    positive("dt_s", dt_s)
    positive("peak_nm", peak_nm)
    if band_hz[1] >= 0.5 / dt_s:
        raise ValueError(f"band_hz upper edge must lie below the Nyquist frequency {0.5 / dt_s:g} Hz, got {band_hz!r}")
    f = multisine_frequencies_hz(period_s, band_hz)
    k = np.arange(1, f.size + 1)
    phase = -math.pi * k * (k - 1) / f.size

    def wave(steps: int) -> np.ndarray:
        return np.cos(2 * math.pi * np.outer(np.arange(steps) * dt_s, f) + phase).sum(axis=1)

    scale = peak_nm / np.max(np.abs(wave(max(int(round(period_s / dt_s)), 1))))  # the peak of one period
    return np.clip(scale * wave(n_steps), -peak_nm, peak_nm)

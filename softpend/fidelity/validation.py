"""Cantilever experiments on either plant (hub locked) against Euler-Bernoulli theory: bending frequencies fitted
to a free-vibration run (FFT start, least-squares refinement) and the static tip sag from Exudyn's static solver."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Optional, Sequence

import numpy as np

from softpend.checks import int_at_least, one_of
from softpend.plant import RodParams, make_plant
from softpend.plant.base import PlantBase

#: Roots ``beta_k L`` of ``1 + cos(beta L) cosh(beta L) = 0`` (clamped-free beam), first three modes.
EULER_BERNOULLI_BETA_L: tuple[float, ...] = (1.875104068711961, 4.694091132974175, 7.854757438237613)


def euler_bernoulli_frequencies_hz(params: RodParams, n_modes: int = 2) -> np.ndarray:
    """Bending frequencies [Hz] of the clamped-free rod without tip mass (at most three modes)."""
    if not 1 <= n_modes <= len(EULER_BERNOULLI_BETA_L):
        raise ValueError(f"n_modes must be in [1, {len(EULER_BERNOULLI_BETA_L)}], got {n_modes!r}")
    mu = params.mass_kg / params.length_m
    beta_l = np.asarray(EULER_BERNOULLI_BETA_L[:n_modes])
    return beta_l**2 / (2 * math.pi * params.length_m**2) * math.sqrt(params.bending_stiffness_nm2 / mu)


def euler_bernoulli_mode_shape(mode: int, s_over_l: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cantilever mode shape ``w_k(s / L)`` (1-based ``mode``, tip value 2 in magnitude) and its slope ``L dw_k/ds``."""
    if not 1 <= mode <= len(EULER_BERNOULLI_BETA_L):
        raise ValueError(f"mode must be in [1, {len(EULER_BERNOULLI_BETA_L)}], got {mode!r}")
    b = EULER_BERNOULLI_BETA_L[mode - 1]
    x = b * np.asarray(s_over_l, dtype=float)
    sigma = (math.cosh(b) + math.cos(b)) / (math.sinh(b) + math.sin(b))
    shape = np.cosh(x) - np.cos(x) - sigma * (np.sinh(x) - np.sin(x))
    slope = b * (np.sinh(x) + np.sin(x) - sigma * (np.cosh(x) - np.cos(x)))
    return shape, slope


def deflected_state(plant: Any, lateral_m, slope) -> tuple[np.ndarray, np.ndarray]:
    """State at rest of a hub-locked plant whose rod follows a lateral deflection ``lateral_m(s)`` [m] with slope
    ``slope(s)`` (arc length ``s`` [m], in the hub frame)."""
    p = plant.params
    q = np.zeros(plant.n_coordinates)
    if hasattr(plant, "n_elements"):  # the beam: (u, v, psi) per node after the hub
        s = np.linspace(0.0, p.length_m, plant.n_elements + 1)[1:]
        local = q.reshape(plant.n_elements, 3)
        local[:, 0] = lateral_m(s)
        local[:, 2] = -np.arctan(slope(s))  # the tangent (-sin psi, cos psi) follows (u', 1)
    else:  # the PRB chain: joints at s_j = j L/n, link angles follow the chords of u(s)
        s = np.linspace(0.0, p.length_m, p.n_links + 1)
        absolute = -np.arctan2(np.diff(lateral_m(s)), np.diff(s))
        q[:] = np.diff(np.concatenate([[0.0], absolute]))
    return q, np.zeros(plant.n_coordinates)


@dataclass
class FreeVibration:
    """A free-vibration run of a cantilever: tip signal, the frequencies fitted to it, and theory's."""

    plant: str
    resolution: int
    time_s: np.ndarray
    tip_x_m: np.ndarray
    frequencies_hz: np.ndarray
    theory_hz: np.ndarray

    @property
    def error_pct(self) -> np.ndarray:
        """Error of the measured frequencies against Euler-Bernoulli [%]."""
        return 100.0 * (self.frequencies_hz / self.theory_hz - 1.0)


def _resolved(plant: str, params: RodParams, resolution: Optional[int]) -> tuple[RodParams, int, dict[str, Any]]:
    """The parameters, the resolution (default: the plant's) and the plant's keyword for it."""
    one_of("plant", plant, ("beam", "prb"))
    if resolution is None:
        from softpend.plant.beam import DEFAULT_N_ELEMENTS

        resolution = DEFAULT_N_ELEMENTS if plant == "beam" else params.n_links
    resolution = int_at_least("resolution", resolution, 1)
    if plant == "prb":
        return params.replace(n_links=resolution), resolution, {}
    return params, resolution, {"n_elements": resolution}


def cantilever_free_vibration(
    plant: str = "beam",
    params: Optional[RodParams] = None,
    resolution: Optional[int] = None,
    dt_s: float = 5e-4,
    modes: Sequence[int] = (1, 2),
) -> FreeVibration:
    """Release the hub-locked, gravity-free, undamped rod from the sum of the ``modes``' shapes (tip amplitude
    ``L/500`` each) and fit one frequency per mode over six periods of the slowest.  ``resolution`` is the beam's
    ``n_elements`` or the chain's ``n_links``."""
    params = (params or RodParams()).replace(gravity_mps2=0.0, joint_damping_nms_per_rad=0.0, tip_mass_kg=0.0)
    params, resolution, resolution_kwargs = _resolved(plant, params, resolution)
    modes = [int(m) for m in modes]
    theory = euler_bernoulli_frequencies_hz(params, max(modes))[np.asarray(modes) - 1]
    duration_s = 6.0 / float(theory[0]) if 1 in modes else 6.0 / float(np.min(theory))
    length = params.length_m
    amplitude = length / 500.0  # of each mode at the tip
    kwargs = dict(params=params, dt_s=dt_s, substeps=1, hub_locked_at_rad=0.0, spectral_radius=1.0, **resolution_kwargs)
    sim = make_plant(plant, **kwargs, **({"newton_relative_tolerance": 1e-10} if plant == "beam" else {}))

    def shape(s, k):  # k = 0: the lateral deflection, 1: its slope
        return sum(0.5 * amplitude * euler_bernoulli_mode_shape(m, s / length)[k] / (length if k else 1) for m in modes)

    sim.reset(*deflected_state(sim, lambda s: shape(s, 0), lambda s: shape(s, 1)))
    n_steps = int(round(duration_s / dt_s))
    tip = np.array([sim.observe().ex_m] + [sim.step(0.0).ex_m for _ in range(n_steps)])
    time = np.arange(n_steps + 1) * dt_s
    return FreeVibration(plant, resolution, time, tip, fit_modal_frequencies_hz(time, tip, theory), theory)


def _fft_peak_hz(time_s: np.ndarray, signal: np.ndarray, band_hz: tuple[float, float]) -> float:
    """Largest peak of the Hann-windowed, zero-padded spectrum inside ``band_hz`` (parabolic interpolation)."""
    dt = float(time_s[1] - time_s[0])
    x = (signal - np.mean(signal)) * np.hanning(len(signal))
    n_fft = 16 * int(2 ** math.ceil(math.log2(len(x))))
    spectrum = np.abs(np.fft.rfft(x, n_fft))
    freq = np.fft.rfftfreq(n_fft, dt)
    inside = np.flatnonzero((freq >= band_hz[0]) & (freq <= band_hz[1]))
    if inside.size < 3:
        raise ValueError(f"band {band_hz} Hz holds no spectral line; run longer or sample faster")
    i = int(inside[np.argmax(spectrum[inside])])
    if 0 < i < len(spectrum) - 1:
        a, b, c = np.log(spectrum[i - 1 : i + 2] + 1e-300)
        denom = a - 2 * b + c
        offset = 0.5 * (a - c) / denom if denom != 0 else 0.0
        return float(freq[i] + offset * (freq[1] - freq[0]))
    return float(freq[i])


def fit_modal_frequencies_hz(time_s: np.ndarray, signal: np.ndarray, centres_hz: Sequence[float]) -> np.ndarray:
    """Least-squares frequencies [Hz] of the sinusoids in a uniformly sampled signal, one per rough centre (started
    from the largest FFT peak within bands cut half-way between neighbouring centres)."""
    from scipy.optimize import least_squares

    t, y = np.asarray(time_s, dtype=float), np.asarray(signal, dtype=float)
    centres = np.sort(np.asarray(centres_hz, dtype=float))
    lows = [centres[0] / 2] + [math.sqrt(a * b) for a, b in zip(centres[:-1], centres[1:])]
    highs = lows[1:] + [centres[-1] * 2]
    start = np.array([_fft_peak_hz(t, y, (lo, hi)) for lo, hi in zip(lows, highs)])
    scale = float(np.max(np.abs(y))) or 1.0

    def residual(freqs):  # of the best fit of a constant and the sinusoids
        a = np.stack([np.ones_like(t)] + [w(2 * math.pi * f * t) for f in freqs for w in (np.cos, np.sin)], axis=1)
        coef, *_ = np.linalg.lstsq(a, y / scale, rcond=None)
        return a @ coef - y / scale

    fit = least_squares(residual, start, x_scale=start * 1e-3, xtol=1e-12, ftol=1e-12)
    return np.asarray(fit.x)


def measured_bending_frequencies(
    plant: str = "beam", params: Optional[RodParams] = None, resolution: Optional[int] = None
) -> dict[str, float]:
    """First two cantilever frequencies from a free-vibration run and their error against theory."""
    run = cantilever_free_vibration(plant, params, resolution)
    values = {"hz": run.frequencies_hz, "theory_hz": run.theory_hz, "error_pct": run.error_pct}
    return {f"f{k + 1}_{key}": float(v[k]) for k in (0, 1) for key, v in values.items()}


def static_tip_sag(
    plant: str = "beam", params: Optional[RodParams] = None, resolution: Optional[int] = None
) -> dict[str, float]:
    """Tip drop of the horizontally clamped rod under gravity from the plant's static solver, beside the
    small-deflection theory's."""
    params, _, resolution_kwargs = _resolved(plant, params or RodParams(), resolution)
    sim = make_plant(plant, params=params, hub_locked_at_rad=math.pi / 2, **resolution_kwargs)
    assert isinstance(sim, PlantBase)  # the PRB and beam plants: Exudyn's static solver
    observation = sim.static_equilibrium()
    theory = params.static_sag_euler_bernoulli_m
    sag, x, y = -observation.ey_m, observation.ex_m, observation.ey_m
    values = {"sag_m": sag, "tip_x_m": x, "tip_y_m": y, "theory_m": theory, "error_pct": 100.0 * (sag / theory - 1.0)}
    return {key: float(value) for key, value in values.items()}

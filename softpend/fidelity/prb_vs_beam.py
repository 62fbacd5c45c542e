"""How the pseudo-rigid-body chain approaches the continuum beam as ``n_links`` grows: cantilever frequencies,
static sag (small and large deflection) and the tip trajectory under one open-loop torque, against the beam."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from softpend.fidelity.validation import (
    _resolved,
    cantilever_free_vibration,
    measured_bending_frequencies,
    static_tip_sag,
)
from softpend.plant import RodParams, make_plant

#: ``stiffness_scale`` of the small-deflection sag case.
SMALL_DEFLECTION_STIFFNESS_SCALE = 100.0


def tip_trajectory_m(plant: str, params: RodParams, torques_nm: np.ndarray, resolution: Optional[int]) -> np.ndarray:
    """Tip positions ``(T + 1, 2)`` [m] of a plant (``resolution``: elements or links) started hanging at rest, at
    0.01 s steps."""
    params, _, resolution_kwargs = _resolved(plant, params, resolution)
    sim = make_plant(plant, params=params, dt_s=0.01, **resolution_kwargs)
    path = [sim.reset(*sim.hanging_state())] + [sim.step(float(torque)) for torque in torques_nm]
    return np.array([(o.ex_m, o.ey_m) for o in path])


@dataclass
class ConvergenceRow:
    """One line of :func:`convergence_table` (errors in %, trajectory error relative to ``L``)."""

    plant: str
    resolution: int
    f1_error_pct: float
    f2_error_pct: float
    sag_small_error_pct: float
    sag_large_vs_beam_pct: float
    tip_rms_over_l: float
    tip_max_over_l: float


def convergence_table(
    n_links: Sequence[int] = (1, 2, 3, 4, 6, 8, 12, 16),
    beam_elements: Sequence[int] = (4, 8, 12, 16, 24),
    params: Optional[RodParams] = None,
    trajectory_s: float = 4.0,
    reference_elements: Optional[int] = None,
) -> list[ConvergenceRow]:
    """PRB chains of ``n_links`` and beams of ``beam_elements`` against theory and the reference beam (default:
    the beam plant's default elements); beam rows first, a one-link chain has no second mode (``nan``)."""
    from softpend.plant.beam import DEFAULT_N_ELEMENTS

    params = params or RodParams()
    reference = reference_elements or DEFAULT_N_ELEMENTS
    stiff = params.replace(stiffness_scale=params.stiffness_scale * SMALL_DEFLECTION_STIFFNESS_SCALE)
    t = np.arange(int(round(trajectory_s / 0.01))) * 0.01  # pumps the swing (1 Hz), excites the first mode (3.1 Hz)
    u = np.sin(2 * math.pi * 1.0 * t) + 0.4 * np.sin(2 * math.pi * 3.1 * t)
    torques = params.torque_limit_nm * np.clip(u, -1.0, 1.0)
    beam_sag = static_tip_sag("beam", params, reference)["sag_m"]
    beam_tip = tip_trajectory_m("beam", params, torques, resolution=reference)
    jobs = [("beam", int(n)) for n in beam_elements] + [("prb", int(n)) for n in n_links]
    rows = []
    for plant, n in jobs:
        if plant == "prb" and n == 1:
            f1 = float(cantilever_free_vibration("prb", params, 1, modes=(1,)).error_pct[0])
            f2 = math.nan
        else:
            freqs = measured_bending_frequencies(plant, params, n)
            f1, f2 = freqs["f1_error_pct"], freqs["f2_error_pct"]
        sag_small = static_tip_sag(plant, stiff, n)["error_pct"]
        sag_large = 100.0 * (static_tip_sag(plant, params, n)["sag_m"] / beam_sag - 1.0)
        tip = tip_trajectory_m(plant, params, torques, resolution=n)
        distance = np.linalg.norm(tip - beam_tip, axis=1) / params.length_m
        rms, worst = float(np.sqrt(np.mean(distance**2))), float(distance.max())
        rows.append(ConvergenceRow(plant, n, f1, f2, sag_small, sag_large, rms, worst))
    return rows


def recommend_n_links(
    rows: Sequence[ConvergenceRow], tolerance_pct: float = 2.0, tip_rms_tolerance: float = 0.05
) -> Optional[int]:
    """Smallest PRB ``n_links`` whose first-frequency and sag errors (``tolerance_pct``) and tip RMS distance to the
    beam (``tip_rms_tolerance * L``) pass there and at every larger ``n`` tested; ``None`` if none does."""
    prb = sorted((r for r in rows if r.plant == "prb"), key=lambda r: r.resolution)
    errors = ("f1_error_pct", "sag_small_error_pct", "sag_large_vs_beam_pct")
    ok = [
        all(abs(getattr(r, e)) <= tolerance_pct for e in errors) and r.tip_rms_over_l <= tip_rms_tolerance for r in prb
    ]
    return next((r.resolution for i, r in enumerate(prb) if all(ok[i:])), None)

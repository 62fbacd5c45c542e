"""The beam plant against Euler-Bernoulli theory, measured from simulations (not from formulas)."""

import math

import numpy as np
import pytest

from softpend.fidelity.prb_vs_beam import convergence_table, recommend_n_links
from softpend.fidelity.validation import (
    cantilever_free_vibration,
    euler_bernoulli_frequencies_hz,
    fit_modal_frequencies_hz,
    static_tip_sag,
)
from softpend.plant import RodParams
from softpend.plant.beam import DEFAULT_N_ELEMENTS


def test_frequency_fit_recovers_known_sinusoids():
    t = np.arange(4000) * 5e-4
    signal = 0.3 + np.cos(2 * math.pi * 2.9 * t + 0.3) + 0.5 * np.sin(2 * math.pi * 18.7 * t)
    np.testing.assert_allclose(fit_modal_frequencies_hz(t, signal, [3.1, 17.0]), [2.9, 18.7], rtol=1e-6)


def test_first_two_frequencies_within_two_percent_from_free_vibration():
    run = cantilever_free_vibration("beam", RodParams(), DEFAULT_N_ELEMENTS)
    # the tip really vibrates in both modes (tip amplitude L/500 each)
    assert np.ptp(run.tip_x_m) > 1.5 * 0.3 / 500
    assert np.all(np.abs(run.error_pct) < 2.0), run.error_pct
    # and the measurement is sharp enough to see the elements: 4 elements miss mode 2 by > 10 %
    coarse = cantilever_free_vibration("beam", RodParams(), 4)
    assert coarse.error_pct[1] > 10.0
    assert abs(coarse.error_pct[1]) > abs(run.error_pct[1])


def test_frequencies_scale_with_stiffness():
    soft = cantilever_free_vibration("beam", RodParams(stiffness_scale=0.25), 8, modes=(1,), dt_s=2e-3)
    assert soft.frequencies_hz[0] == pytest.approx(0.5 * euler_bernoulli_frequencies_hz(RodParams())[0], rel=0.02)


def test_static_sag_within_two_percent_and_large_deflection_is_not_linear():
    stiff = static_tip_sag("beam", RodParams(stiffness_scale=100.0))
    assert abs(stiff["error_pct"]) < 2.0
    assert stiff["sag_m"] > 0
    soft = static_tip_sag("beam", RodParams())  # 21 % of L: small-deflection theory over-predicts
    assert soft["sag_m"] > 0.15 * soft["theory_m"]
    assert soft["error_pct"] < -2.0


def test_prb_converges_to_beam_and_recommendation():
    rows = convergence_table(n_links=(2, 8), beam_elements=(), trajectory_s=1.0)
    by_n = {r.resolution: r for r in rows}
    for key in ("f1_error_pct", "sag_small_error_pct", "sag_large_vs_beam_pct"):
        assert abs(getattr(by_n[8], key)) < abs(getattr(by_n[2], key))
    assert by_n[8].tip_rms_over_l < by_n[2].tip_rms_over_l
    assert recommend_n_links(rows) == 8
    assert recommend_n_links(rows, tolerance_pct=0.1) is None

"""The shared argument checks: good values pass (converted), bad ones raise ``ValueError`` naming the parameter."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softpend import checks

NOT_NUMBERS = [True, False, np.bool_(True), "1", None, [1.0], (1,)]
NOT_FINITE = [math.nan, math.inf, -math.inf, np.float64("nan")]


@pytest.mark.parametrize(
    "value, expected", [(1, 1.0), (0.25, 0.25), (np.float32(2.0), 2.0), (np.int64(3), 3.0), (1e-300, 1e-300)]
)
def test_positive_accepts_positive_finite_numbers_as_float(value, expected):
    result = checks.positive("dt_s", value)
    assert result == expected and type(result) is float


@pytest.mark.parametrize("value", [0, 0.0, -1e-9, -3, *NOT_FINITE, *NOT_NUMBERS])
def test_positive_rejects_with_the_name_and_value(value):
    with pytest.raises(ValueError, match=r"^dt_s must be positive and finite, got "):
        checks.positive("dt_s", value)


def test_optional_positive_passes_none():
    assert checks.optional_positive("tip_reach_m", None) is None
    assert checks.optional_positive("tip_reach_m", 2) == 2.0
    for value in (0.0, math.nan, True, "x"):
        with pytest.raises(ValueError, match=r"^tip_reach_m must be positive and finite or None"):
            checks.optional_positive("tip_reach_m", value)


@pytest.mark.parametrize("value", [0, 0.0, 5, 2.5, np.float64(1e3)])
def test_non_negative_accepts_zero_and_above(value):
    assert checks.non_negative("noise_std", value) == float(value)


@pytest.mark.parametrize("value", [-1e-12, -1, *NOT_FINITE, *NOT_NUMBERS])
def test_non_negative_rejects(value):
    with pytest.raises(ValueError, match=r"^noise_std must be non-negative and finite, got "):
        checks.non_negative("noise_std", value)


def test_finite_accepts_any_finite_number_and_rejects_the_rest():
    assert checks.finite("offset_rad", -2) == -2.0
    for value in [*NOT_FINITE, *NOT_NUMBERS]:
        with pytest.raises(ValueError, match=r"^offset_rad must be finite"):
            checks.finite("offset_rad", value)


@pytest.mark.parametrize("value, expected", [(1, 1), (7, 7), (np.int32(4), 4), (3.0, 3)])
def test_positive_int_accepts_integers_and_integral_floats(value, expected):
    result = checks.positive_int("episodes", value)
    assert result == expected and type(result) is int


@pytest.mark.parametrize("value", [0, -2, 1.5, *NOT_FINITE, *NOT_NUMBERS])
def test_positive_int_rejects(value):
    with pytest.raises(ValueError, match=r"^episodes must be a positive integer, got "):
        checks.positive_int("episodes", value)


def test_int_at_least_uses_its_bound():
    assert checks.int_at_least("n_torque_levels", 2, 2) == 2
    assert checks.int_at_least("camera_delay_steps", 0, 0) == 0
    assert type(checks.int_at_least("substeps", np.int64(5), 1)) is int
    for value in (1, 2.5, True, math.nan, math.inf, "3"):
        with pytest.raises(ValueError, match=r"^n_torque_levels must be an integer >= 2, got "):
            checks.int_at_least("n_torque_levels", value, 2)


def test_in_unit_interval_closed_and_half_open():
    assert checks.in_unit_interval("gamma", 0) == 0.0
    assert checks.in_unit_interval("gamma", 1) == 1.0
    assert checks.in_unit_interval("gamma", 0.5) == 0.5
    for value in (-0.01, 1.01, True, math.nan, math.inf, "0.5"):
        with pytest.raises(ValueError, match=r"^gamma must lie in \[0, 1\], got "):
            checks.in_unit_interval("gamma", value)
    with pytest.raises(ValueError, match=r"^tau must lie in \(0, 1\], got 0"):
        checks.in_unit_interval("tau", 0.0, include_zero=False)
    assert checks.in_unit_interval("tau", 1.0, include_zero=False) == 1.0
    with pytest.raises(ValueError, match=r"^fraction must lie in \(0, 1\), got 1"):
        checks.in_unit_interval("fraction", 1, include_zero=False, include_one=False)


def test_one_of_returns_the_value_and_lists_the_choices():
    assert checks.one_of("start", "hanging", ("hanging", "upright")) == "hanging"
    assert checks.one_of("activation", "silu", {"silu": 1, "tanh": 2}) == "silu"
    with pytest.raises(ValueError, match=r"^start must be one of \['hanging', 'upright'\], got 'sideways'"):
        checks.one_of("start", "sideways", ("hanging", "upright"))
    with pytest.raises(ValueError, match=r"^activation must be one of \['silu', 'tanh'\], got \[1\]"):
        checks.one_of("activation", [1], {"tanh": 2, "silu": 1})  # unhashable, and a dict's keys sorted


def test_boolean_accepts_bools_only():
    assert checks.boolean("double_q", True) is True
    assert checks.boolean("double_q", np.bool_(False)) is False
    for value in (0, 1, 1.0, "true", None):
        with pytest.raises(ValueError, match=r"^double_q must be a bool, got "):
            checks.boolean("double_q", value)

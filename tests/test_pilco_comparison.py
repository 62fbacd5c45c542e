"""The head-to-head bookkeeping of Figure 10 on hand-made records: rows, seconds to balance, the cost plot."""

from __future__ import annotations

import math
from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest

from softpend.pilco.loop import TrialRecord
from softpend.study.head_to_head import curve_rows_pilco, plot_predicted_and_real_cost, seconds_to_balance_table


def record(index, kind, plant_s, predicted, real, success=math.nan, std=math.nan):
    return TrialRecord(
        index=index,
        kind=kind,
        duration_s=6.0,
        plant_seconds_total=plant_s,
        predicted_cost=predicted,
        real_cost=real,
        swing_up_time_s=math.nan,
        upright_std_rad=math.nan,
        n_gp_points=10,
        wall_s_total=1.0,
        eval_success_rate=success,
        eval_upright_std_rad=std,
    )


def fake_result(seed, records):
    return SimpleNamespace(config=SimpleNamespace(seed=seed), records=records)


RESULTS = [
    fake_result(
        0,
        [
            record(0, "random", 6, math.nan, 60),
            record(1, "policy", 12, 50, 40, 0.0, 1.5),
            record(2, "policy", 18, 20, 15, 1.0, 0.05),
        ],
    ),
    fake_result(1, [record(0, "random", 6, math.nan, 59), record(1, "policy", 12, 30, 12, 1.0, 0.15)]),
]


def test_rows_and_seconds_to_balance():
    rows = curve_rows_pilco(RESULTS)
    assert [(r["seed"], r["plant_s"]) for r in rows] == [(0, 12), (0, 18), (1, 12)]  # the random trial has no test
    table = seconds_to_balance_table(rows, std_levels_rad=(0.2, 0.1))
    assert len(table) == 1 and table[0]["seeds"] == 2
    assert table[0]["plant_s_to_std_0.2_rad"] == pytest.approx(15.0)  # median of 18 and 12
    assert table[0]["plant_s_to_std_0.1_rad"] == math.inf  # seed 1 never gets within 0.1 rad: the median is inf
    assert table[0]["final_max_upright_std_rad"] == pytest.approx(0.1)


def test_cost_plot_draws_predicted_and_real_per_policy_trial():
    fig = plot_predicted_and_real_cost(RESULTS)
    lines = fig.axes[0].get_lines()
    assert len(lines) == 4  # predicted and real for each seed
    np.testing.assert_array_equal(lines[0].get_xdata(), [1, 2])
    np.testing.assert_array_equal(lines[0].get_ydata(), [50, 20])
    np.testing.assert_array_equal(lines[1].get_ydata(), [40, 15])
    assert lines[0].get_color() == lines[1].get_color() and lines[0].get_linestyle() == "--"
    ticks = [t for t in fig.axes[0].get_xticks() if 1 <= t <= 2]
    assert all(float(t).is_integer() for t in ticks)

"""The paired plant-seconds ratio of the data-efficiency chapter and bench (softpend.study.data_efficiency)."""

import math

from softpend.study.data_efficiency import paired_ratio, paired_ratio_rows, pilco_rows_if_trained


def test_paired_ratio_by_seed_with_seeds_that_never_balance():
    planner = {0: 10.0, 1: 12.0, 2: math.inf, 3: 9.0, 4: math.inf, 7: 5.0}
    pilco = {0: 20.0, 1: 24.0, 2: 18.0, 3: math.inf, 4: math.inf, 5: 30.0}
    rows = paired_ratio_rows(planner, pilco)
    assert [r["seed"] for r in rows] == [0, 1, 2, 3, 4]  # seeds held by both only
    assert [r["ratio"] for r in rows] == [0.5, 0.5, math.inf, 0.0, math.inf]
    assert rows[0] == {"seed": 0, "numerator_s": 10.0, "denominator_s": 20.0, "ratio": 0.5}
    assert paired_ratio(planner, pilco) == 0.5  # median of 0, 0.5, 0.5, inf, inf
    assert paired_ratio({0: 10.0, 1: 30.0}, {0: 20.0, 1: 20.0}) == 1.0  # median of 0.5 and 1.5
    assert math.isnan(paired_ratio({0: 1.0}, {1: 1.0}))


def test_pilco_rows_are_not_trained_where_absent(tmp_path):
    assert pilco_rows_if_trained([0, 1], tmp_path / "absent") is None
    assert pilco_rows_if_trained([0, 1], tmp_path) is None
    assert list(tmp_path.iterdir()) == []

"""Fresh-start measurement of trained controllers: counts, intervals, and refusal of selection starts."""

import math

import numpy as np
import pytest

from softpend.evaluation import EvaluationResult, EvaluationSummary
from softpend.rl.config import DQNConfig
from softpend.rl.dqn import train_dqn
from softpend.stats import wilson_interval
from softpend.study.fresh_starts import aggregate_fresh_start_rows, fresh_start_row, rl_fresh_start_rows


def _result(seed, swing_up_s, std):
    empty = np.zeros((2, 10))
    return EvaluationResult(seed=seed, swing_up_time_s=swing_up_s, upright_std_rad=std, upright_mean_abs_rad=std,
                            peak_torque_nm=0.06, energy_used_j=0.1, success=math.isfinite(swing_up_s) and std <= 0.2,
                            time_s=np.zeros(2), observations=empty, torque_nm=np.zeros(2), joint_angles_rad=empty)


def test_a_start_balances_only_when_it_swings_up_and_holds_within_the_threshold():
    results = [_result(i, 2.0, 0.05) for i in range(17)] + [_result(17, 2.0, 0.15), _result(18, math.inf, 0.05),
                                                             _result(19, 3.0, 0.09)]
    row = fresh_start_row(EvaluationSummary("x", results))
    assert row["starts"] == 20 and row["balanced_starts"] == 18
    assert (row["balanced_low"], row["balanced_high"]) == pytest.approx(wilson_interval(18, 20))
    assert row["run_balances"] and row["worst_balanced_std_rad"] == pytest.approx(0.09)
    assert row["success_rate"] == pytest.approx(19 / 20)  # the 0.15 rad start succeeds at 0.2 rad
    worse = fresh_start_row(EvaluationSummary("x", results[:16] + [_result(16, math.inf, 1.0)] * 4))
    assert worse["balanced_starts"] == 16 and not worse["run_balances"]  # 80 % < 90 %


def test_aggregate_counts_runs_and_bootstraps_the_iqm():
    rows = [{"method": "m", "agent": "final", "balanced_rate": r, "run_balances": r >= 0.9}
            for r in (1.0, 0.95, 0.9, 0.5, 0.0)]
    (agg,) = aggregate_fresh_start_rows(rows)
    assert agg["runs"] == 5 and agg["runs_balanced"] == 3
    assert agg["iqm_low"] <= agg["iqm_balanced_rate"] <= agg["iqm_high"]
    (single,) = aggregate_fresh_start_rows(rows[:1])
    assert single["iqm_balanced_rate"] == 1.0 and math.isnan(single["iqm_low"])


def test_rl_rows_come_from_the_run_folders_and_refuse_selection_starts(tmp_path):
    config = DQNConfig(episode_s=0.4, learning_starts=5, eval_seeds=(7,), eval_duration_s=0.3)
    train_dqn(config, seed=0, episodes=1, run_dir=tmp_path / "dqn-seed0", progress=False)
    rows = rl_fresh_start_rows(tmp_path, [0], algos=["dqn"], report_seeds=(20_000, 20_001), duration_s=1.2)
    assert [(r["agent"], r["starts"]) for r in rows] == [("selected", 2), ("final", 2)]
    assert all(r["balanced_starts"] == 0 for r in rows)  # one 0.4 s episode of training balances nothing
    with pytest.raises(ValueError, match="select"):
        rl_fresh_start_rows(tmp_path, [0], algos=["dqn"], report_seeds=(7, 20_000), duration_s=1.2)

"""Fresh-start measurement of trained controllers: counts, intervals, and refusal of selection starts."""

import inspect
import json
import math

import numpy as np
import pytest

from softpend.evaluation import TEST_EPISODE_S, EvaluationResult, EvaluationSummary
from softpend.pilco.loop import PilcoConfig
from softpend.rl.config import DQNConfig
from softpend.rl.dqn import train_dqn
from softpend.stats import wilson_interval
from softpend.study import fresh_starts
from softpend.study.fresh_starts import aggregate_fresh_start_rows, fresh_start_row, rl_fresh_start_rows


def _result(seed, swing_up_s, std):
    empty = np.zeros((2, 10))
    return EvaluationResult(
        seed=seed,
        swing_up_time_s=swing_up_s,
        upright_std_rad=std,
        upright_mean_abs_rad=std,
        peak_torque_nm=0.06,
        energy_used_j=0.1,
        success=math.isfinite(swing_up_s) and std <= 0.2,
        time_s=np.zeros(2),
        observations=empty,
        torque_nm=np.zeros(2),
        joint_angles_rad=empty,
    )


def test_a_start_balances_only_when_it_swings_up_and_holds_within_the_threshold():
    results = [_result(i, 2.0, 0.05) for i in range(17)] + [
        _result(17, 2.0, 0.15),
        _result(18, math.inf, 0.05),
        _result(19, 3.0, 0.09),
    ]
    row = fresh_start_row(EvaluationSummary("x", results))
    assert row["starts"] == 20 and row["balanced_starts"] == 18
    assert (row["balanced_low"], row["balanced_high"]) == pytest.approx(wilson_interval(18, 20))
    assert row["run_balances"] and row["worst_balanced_std_rad"] == pytest.approx(0.09)
    assert row["success_rate"] == pytest.approx(19 / 20)  # the 0.15 rad start succeeds at 0.2 rad
    worse = fresh_start_row(EvaluationSummary("x", results[:16] + [_result(16, math.inf, 1.0)] * 4))
    assert worse["balanced_starts"] == 16 and not worse["run_balances"]  # 80 % < 90 %


def test_the_tests_that_stop_or_select_a_run_are_as_long_as_the_reported_fresh_start_episodes():
    # a policy that holds for a shorter selection test and falls later must not stop a run as balanced
    assert DQNConfig().eval_duration_s == PilcoConfig().eval_duration_s == TEST_EPISODE_S
    for function in (
        fresh_starts.rl_fresh_start_rows,
        fresh_starts.pilco_fresh_start_rows,
        fresh_starts.perturbed_rod_row,
    ):
        assert inspect.signature(function).parameters["duration_s"].default == TEST_EPISODE_S, function.__name__


def test_aggregate_counts_runs_and_bootstraps_the_iqm():
    rows = [
        {"method": "m", "agent": "final", "balanced_rate": r, "run_balances": r >= 0.9}
        for r in (1.0, 0.95, 0.9, 0.5, 0.0)
    ]
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


def test_rl_rows_are_kept_in_the_run_folder_and_measured_again_when_the_agent_changes(tmp_path, monkeypatch):
    import softpend.rl.dqn as dqn
    from softpend.study.fresh_starts import FRESH_STARTS_FILE

    config = DQNConfig(episode_s=0.4, learning_starts=5, eval_seeds=(7,), eval_duration_s=0.3)
    folder = tmp_path / "dqn-seed0"
    train_dqn(config, seed=0, episodes=1, run_dir=folder, progress=False)
    first = rl_fresh_start_rows(tmp_path, [0], algos=["dqn"], report_seeds=(20_000,), duration_s=1.0)
    assert (folder / FRESH_STARTS_FILE).is_file()
    calls = []
    real = dqn.evaluate_agent
    monkeypatch.setattr(dqn, "evaluate_agent", lambda *a, **k: calls.append(1) or real(*a, **k))
    again = rl_fresh_start_rows(tmp_path, [0], algos=["dqn"], report_seeds=(20_000,), duration_s=1.0)
    assert json.dumps(again) == json.dumps(first)  # NaN-aware equality
    assert calls == []  # both agents read back
    rl_fresh_start_rows(tmp_path, [0], algos=["dqn"], report_seeds=(20_001,), duration_s=1.0)
    assert len(calls) == 2  # other starts: measured
    train_dqn(config, seed=1, episodes=1, run_dir=tmp_path / "other", progress=False)
    (folder / "agent.zip").write_bytes((tmp_path / "other" / "agent.zip").read_bytes())  # another final agent
    calls.clear()  # (training evaluates too)
    rl_fresh_start_rows(tmp_path, [0], algos=["dqn"], report_seeds=(20_001,), duration_s=1.0)
    assert len(calls) == 1  # only the changed agent is measured again


def _log(seed: int, plant_s: float, stopped: bool):
    from softpend.rl.training_log import TrainingLog

    log = TrainingLog(
        "dqn", seed, episodes=[{"episode": 1, "plant_s": plant_s}], stop_reason="balanced" if stopped else None
    )
    return log


def test_headline_figures_count_final_agents_and_compare_plant_seconds_seed_by_seed():
    from softpend.study.fresh_starts import headline_figures, seed_rows

    # DQN: 300, 400, 500 s; DQN-MBPO: 90 (3.3x fewer), 150 (2.7x) and a run whose final agent fails fresh starts
    dqn = [_log(0, 300.0, True), _log(1, 400.0, True), _log(2, 500.0, False)]
    mbpo = [_log(0, 90.0, True), _log(1, 150.0, True), _log(2, 60.0, True)]
    balanced = {
        ("model-free DQN", 0): 20,
        ("model-free DQN", 1): 19,
        ("model-free DQN", 2): 18,
        ("DQN-MBPO", 0): 20,
        ("DQN-MBPO", 1): 18,
        ("DQN-MBPO", 2): 11,
    }
    fresh = [
        {"method": m, "seed": s, "agent": "final", "balanced_starts": k, "starts": 20, "run_balances": k >= 18}
        for (m, s), k in balanced.items()
    ]
    fresh += [
        {
            "method": "DQN-MBPO",
            "seed": 2,
            "agent": "selected",
            "balanced_starts": 20,
            "starts": 20,
            "run_balances": True,
        }
    ]  # the selected agent does not count
    rows = seed_rows({"dqn": dqn, "mbpo": mbpo}, fresh)
    by = {(r["method"], r["seed"]): r for r in rows}
    assert (
        by[("DQN-MBPO", 2)]["plant_s_to_balance"] == math.inf
        and by[("model-free DQN", 2)]["plant_s_to_balance"] == 500.0
    )
    figures = headline_figures(rows)
    assert figures["seeds_balanced_dqn"] == 3 and figures["seeds_balanced_mbpo"] == 2 and figures["seeds_mbpo"] == 3
    assert figures["dqn_real_s_to_balance"] == 400.0 and figures["mbpo_real_s_to_balance"] == 150.0
    assert figures["mbpo_over_dqn_real_s_ratio"] == pytest.approx(400 / 150)
    assert figures["mbpo_seeds_3x_fewer_than_dqn"] == 1  # seed 0 only (seed 1: 2.7x; seed 2: never)
    assert figures["mbpo_real_s_to_balance_low"] <= 150.0 <= figures["mbpo_real_s_to_balance_high"]
    with pytest.raises(ValueError, match="no fresh-start row"):
        seed_rows({"dqn": dqn}, fresh[1:])


def test_randomised_rods_scale_each_field_within_the_spread_reproducibly():
    from softpend.plant import RodParams
    from softpend.plant.params import RANDOMISED_FIELDS, randomised_rod

    rod = RodParams()
    rods = [randomised_rod(rod, np.random.default_rng(s), 0.15) for s in range(50)]
    for name in RANDOMISED_FIELDS:
        ratios = np.array([getattr(r, name) / getattr(rod, name) for r in rods])
        assert np.all(ratios >= 0.85) and np.all(ratios <= 1.15) and ratios.std() > 0.05
    assert rods[0] == randomised_rod(rod, np.random.default_rng(0), 0.15)
    assert rods[0].length_m == rod.length_m and rods[0].hub_inertia_kgm2 == rod.hub_inertia_kgm2
    assert randomised_rod(rod, np.random.default_rng(0), 0.0) == rod
    for bad in (-0.1, 1.0, float("nan")):
        with pytest.raises(ValueError, match="spread"):
            randomised_rod(rod, np.random.default_rng(0), bad)


def test_perturbed_rod_row_runs_each_start_on_its_own_rod():
    """Each start runs on the rod ``randomised_rod`` draws from ``default_rng(seed)``: the row equals the one of
    evaluations on those rods built by hand, and differs from the nominal rod's."""
    from softpend.control.swingup import EnergySwingUpController
    from softpend.evaluation import evaluate
    from softpend.plant.params import randomised_rod
    from softpend.study.fresh_starts import perturbed_rod_row
    from softpend.task import Task

    task, seeds = Task(), (20_000, 20_001)
    row = perturbed_rod_row(
        EnergySwingUpController(task.rod, dt_s=task.dt_s), task, 0.15, report_seeds=seeds, duration_s=4.0
    )
    by_hand = [
        evaluate(
            EnergySwingUpController(task.rod, dt_s=task.dt_s),
            task.replace(rod=randomised_rod(task.rod, np.random.default_rng(seed), 0.15)),
            seeds=(seed,),
            duration_s=4.0,
        ).results[0]
        for seed in seeds
    ]
    assert row == {"spread": 0.15, **fresh_start_row(EvaluationSummary("by hand", by_hand))}
    assert row["balanced_starts"] == 2  # the swing-up holds both rods: the times below are real catches
    nominal = fresh_start_row(
        evaluate(EnergySwingUpController(task.rod, dt_s=task.dt_s), task, seeds=seeds, duration_s=4.0)
    )
    assert nominal["median_swing_up_time_s"] != row["median_swing_up_time_s"]

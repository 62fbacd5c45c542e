"""RL configs, the learning-curve helpers and the "balanced" / "asymptote" definitions on hand-made data."""

import json
import math

import numpy as np
import pytest

from softpend.evaluation import metrics_from_trajectory
from softpend.io.overrides import apply_overrides, parse_assignment
from softpend.rl.config import (
    DQNConfig,
    DQNLearner,
    MBPOConfig,
    RolloutSettings,
    StopRule,
    load_config,
    save_config,
)
from softpend.rl.curves import episodes_to_asymptote, interval_band, moving_average
from softpend.rl.training_log import TrainingLog


def test_config_validation_names_the_field():
    with pytest.raises(ValueError, match="n_torque_levels"):
        DQNConfig(n_torque_levels=1)
    with pytest.raises(ValueError, match="learner.gamma"):
        DQNLearner(gamma=1.5)
    with pytest.raises(ValueError, match="rollout.schedule"):
        RolloutSettings(schedule=(5, 2, 1, 3))
    with pytest.raises(ValueError, match="rollout.real_ratio"):
        RolloutSettings(real_ratio=-0.1)
    with pytest.raises(ValueError, match="rollout.start_branch_fraction"):
        RolloutSettings(start_branch_fraction=1.5)
    with pytest.raises(ValueError, match="learner.clip_q_targets"):
        DQNLearner(clip_q_targets=1)
    with pytest.raises(ValueError, match="rollout.within_data"):
        apply_overrides(MBPOConfig(), [parse_assignment("rollout.within_data=yes")])
    with pytest.raises(ValueError, match="learner must be a DQNLearner"):
        DQNConfig(learner={"gamma": 0.5})
    with pytest.raises(ValueError, match="unknown"):
        apply_overrides(DQNConfig(), [parse_assignment("no_such_field=1")])


def test_overrides_and_json_round_trip(tmp_path):
    """``--set`` values as the command line reads them: JSON, lists for tuples."""
    config = apply_overrides(
        MBPOConfig(),
        [
            parse_assignment(t)
            for t in ("learner.learning_rate=1e-3", "learner.net_arch=[32, 32]", "rollout.per_real_step=8")
        ],
    )
    assert config.learner.learning_rate == 1e-3 and config.learner.net_arch == (32, 32)
    assert config.rollout.per_real_step == 8
    save_config(config, tmp_path / "c.json")
    assert load_config(tmp_path / "c.json") == config


def test_config_of_another_version_is_a_clear_error(tmp_path):
    (tmp_path / "c.json").write_text('{"class": "MBPOConfig", "model_epochs": 3}')
    with pytest.raises(ValueError, match="'model_epochs' is not a MBPOConfig field"):
        load_config(tmp_path / "c.json")


@pytest.mark.parametrize("config", [DQNConfig(reset_every_episodes=20), MBPOConfig()])
def test_a_saved_config_with_a_field_too_many_or_too_few_is_a_one_line_error(tmp_path, config):
    """No migration: a config saved by a version with other fields names the first field that differs."""
    save_config(config, tmp_path / "c.json")
    data = json.loads((tmp_path / "c.json").read_text())
    (tmp_path / "old.json").write_text(json.dumps({**data, "reset_catch_up_gradient_steps": 0}))
    with pytest.raises(ValueError, match="'reset_catch_up_gradient_steps' is not a") as info:
        load_config(tmp_path / "old.json")
    assert "\n" not in str(info.value)
    del data["stop"]["confirm_max_failures"]
    (tmp_path / "old.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="StopRule field 'confirm_max_failures' is missing") as info:
        load_config(tmp_path / "old.json")
    assert "\n" not in str(info.value)


def test_confirmation_failures_allowed_must_leave_a_start_that_balances():
    assert DQNConfig().stop.confirm_max_failures == 0
    with pytest.raises(ValueError, match="stop.confirm_max_failures"):
        StopRule(confirm_seeds=(5, 6), confirm_max_failures=2)
    with pytest.raises(ValueError, match="stop.confirm_max_failures"):
        StopRule(confirm_max_failures=-1)
    assert StopRule(confirm_seeds=(), confirm_max_failures=3).confirm_max_failures == 3


def test_rollout_schedule_is_linear_like_mbrl_lib():
    rollout = RolloutSettings(schedule=(10, 20, 1, 11))
    assert [rollout.length(e) for e in (0, 10, 15, 20, 50)] == [1, 1, 6, 11, 11]


def test_episode_steps_follow_action_repeat():
    config = DQNConfig(episode_s=5.0, action_repeat=4)
    assert config.episode_agent_steps == 125 and config.agent_dt_s == pytest.approx(0.04)


def test_metrics_on_hand_made_swing_up():
    """Hanging for 2 s, then a sinusoid of amplitude 0.1 rad about upright: swing-up at 2 s, std 0.1/sqrt(2)."""
    t = np.arange(0, 10.0 + 1e-9, 0.01)
    theta = np.where(t < 2.0, np.pi - 0.01, 0.1 * np.sin(2 * np.pi * 1.0 * (t - 2.0)))
    m = metrics_from_trajectory(t, theta, np.full_like(t, 0.03), np.ones_like(t))
    assert m["swing_up_time_s"] == pytest.approx(2.0, abs=0.011)
    assert m["upright_std_rad"] == pytest.approx(0.1 / math.sqrt(2), rel=0.02)
    assert m["success"] and m["peak_torque_nm"] == pytest.approx(0.03)
    # a rod that only passes through the top never counts as swung up
    spinning = np.angle(np.exp(1j * 2 * np.pi * 0.5 * t))
    m = metrics_from_trajectory(t, spinning, np.zeros_like(t), np.zeros_like(t))
    assert math.isinf(m["swing_up_time_s"]) and not m["success"]


def _log(returns, evals):
    log = TrainingLog("dqn", 0)
    for i, r in enumerate(returns):
        log.episodes.append(
            {"episode": i + 1, "return": r, "plant_s": 5.0 * (i + 1), "upright_std_rad": 1.0, "model_steps": 0}
        )
    log.evaluations = evals
    return log


def test_real_s_to_balance_needs_every_seed_up_and_steady():
    evals = [
        {"episode": 10, "plant_s": 50.0, "all_swung_up": False, "max_upright_std_rad": 0.1},
        {"episode": 20, "plant_s": 100.0, "all_swung_up": True, "max_upright_std_rad": 0.3},
        {"episode": 30, "plant_s": 150.0, "all_swung_up": True, "max_upright_std_rad": 0.15},
    ]
    log = _log(np.zeros(30), evals)
    assert log.real_s_to_balance() == 150.0 and log.episodes_to_balance() == 30
    assert math.isinf(log.real_s_to_balance(std_rad=0.1))


def test_asymptote_of_a_saturating_curve():
    episodes = np.arange(1, 201)
    returns = 1000 * (1 - np.exp(-episodes / 30.0))
    e = episodes_to_asymptote(returns, window=1)
    # the final 20 % average ~ 998; 90 % of the rise from ~33 is reached near -30 ln(0.1) ~ 69 episodes
    assert 60 <= e <= 75
    assert episodes_to_asymptote(np.full(50, 3.0)) == 1.0
    # a straight line 0..99: the final-20 % mean is 89.5, 90 % of it (80.55) is first exceeded at episode 82
    assert episodes_to_asymptote(np.arange(100.0), window=1) == 82.0


def test_moving_average():
    np.testing.assert_allclose(moving_average(np.array([1.0, 3.0, 5.0, 7.0]), 2), [1.0, 2.0, 4.0, 6.0])


def _evaluation_log(seed: int, plant_s, stds) -> TrainingLog:
    log = TrainingLog("dqn", seed)
    log.evaluations = [
        {"episode": i + 1, "plant_s": float(t), "max_upright_std_rad": float(v)}
        for i, (t, v) in enumerate(zip(plant_s, stds))
    ]
    return log


def test_interval_band_holds_a_stopped_run_at_its_last_value_and_brackets_the_iqm():
    # eight runs of constant std k / 10 (k = 1..8); run k stops after 5 k plant seconds
    logs = [_evaluation_log(k, np.arange(5.0, 5.0 * k + 1, 5.0), np.full(k, k / 10)) for k in range(1, 9)]
    band = interval_band(logs, grid=np.array([2.0, 5.0, 40.0, 100.0]), n_resamples=500, seed=1)
    np.testing.assert_allclose(band["x"], [5.0, 40.0, 100.0])  # before every run's first row: left out
    np.testing.assert_allclose(band["per_seed"][:, -1], np.arange(1, 9) / 10)  # carried forward
    np.testing.assert_allclose(band["value"], 0.45)  # IQM of 0.1..0.8: mean of 0.3..0.6
    assert np.all(band["low"] < band["value"]) and np.all(band["value"] < band["high"])
    assert np.all(band["low"] >= 0.1) and np.all(band["high"] <= 0.8)
    again = interval_band(logs, grid=np.array([2.0, 5.0, 40.0, 100.0]), n_resamples=500, seed=1)
    np.testing.assert_array_equal(again["low"], band["low"])  # seeded
    # a run whose std falls: the step function takes the latest row at or before each point
    falling = _evaluation_log(0, [5.0, 10.0, 15.0], [1.0, 0.5, 0.05])
    band = interval_band([falling, falling], grid=np.array([5.0, 9.9, 10.0, 30.0]), n_resamples=200)
    np.testing.assert_allclose(band["value"], [1.0, 1.0, 0.5, 0.05])
    with pytest.raises(ValueError, match="at least two runs"):
        interval_band([falling])


def test_training_cpu_s_of_a_log():
    from softpend.study.bench.learning import training_cpu_s

    log = _log(np.zeros(3), [{"episode": 3, "cpu_s": 7.5}])
    for row, cpu in zip(log.episodes, (2.0, 4.0, 6.0)):
        row["cpu_s"] = cpu
    assert training_cpu_s(log) == 7.5  # the final evaluation included
    del log.episodes[0]["cpu_s"]  # a run started before CPU time was logged
    assert math.isnan(training_cpu_s(log))


def test_a_failed_evaluation_counts_at_the_success_level_in_the_worst_start_curve():
    # an evaluation that stopped at its first failing start knows only a lower bound of the worst std (0.15 here,
    # below the success level): with failed_as, every row with a failed start counts as the success level
    from softpend.evaluation import SUCCESS_STD_RAD
    from softpend.rl.curves import failures_as, worst_start_std_rad

    logs = []
    for seed, (rates, stds) in enumerate([([0.0, 0.5, 1.0], [3.0, 0.15, 0.05]), ([0.25, 1.0, 1.0], [0.4, 0.08, 0.06])]):
        log = _evaluation_log(seed, [5.0, 10.0, 15.0], stds)
        for row, rate in zip(log.evaluations, rates):
            row["success_rate"] = rate
        logs.append(log)
    np.testing.assert_allclose(worst_start_std_rad(logs[0]), [SUCCESS_STD_RAD, SUCCESS_STD_RAD, 0.05])
    np.testing.assert_allclose(failures_as([3.0, 0.15, 0.05], [0.0, 0.999, 1.0], 0.2), [0.2, 0.2, 0.05])
    band = interval_band(logs, grid=np.array([5.0, 10.0, 15.0]), n_resamples=200, failed_as=SUCCESS_STD_RAD)
    np.testing.assert_allclose(band["per_seed"], [[0.2, 0.2, 0.05], [0.2, 0.08, 0.06]])
    raw = interval_band(logs, grid=np.array([5.0, 10.0, 15.0]), n_resamples=200)
    np.testing.assert_allclose(raw["per_seed"][0], [3.0, 0.15, 0.05])  # without failed_as: the logged values


def test_balancing_criterion_must_not_be_looser_than_success_when_evaluations_stop_at_a_failure():
    with pytest.raises(ValueError, match="stop.upright_std_rad"):
        DQNConfig(stop=StopRule(upright_std_rad=0.25))
    loose = StopRule(upright_std_rad=0.25)
    assert DQNConfig(stop=loose, eval_until_first_failure=False).stop.upright_std_rad == 0.25
    with pytest.raises(ValueError, match="eval_until_first_failure"):
        DQNConfig(eval_until_first_failure="yes")

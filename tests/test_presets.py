"""The study's presets: one home of the defaults, and reported numbers measured on starts no training or
selection step saw."""

from softpend.study import presets
from softpend.study.rl_runs import figure_configs


def test_report_starts_are_fresh():
    report = set(presets.REPORT_SEEDS)
    assert len(report) == len(presets.REPORT_SEEDS) >= 20
    selection = set(presets.DQN.selection_seeds) | set(presets.MBPO.selection_seeds) | set(presets.PILCO.eval_seeds)
    assert selection <= set(presets.SELECTION_SEEDS)
    assert not report & set(presets.SELECTION_SEEDS)
    training = set(presets.RL_BOOK.seeds) | set(presets.PILCO_BOOK.seeds)
    assert not report & training
    for config in figure_configs().values():  # the book's configs select on the selection seeds only
        assert set(config.selection_seeds) <= set(presets.SELECTION_SEEDS)


def test_the_figures_use_the_presets():
    configs = figure_configs()
    assert configs["dqn"].task == presets.TASK and configs["mbpo"].task == presets.TASK
    assert configs["dqn"] == presets.DQN and configs["mbpo"] == presets.MBPO
    assert presets.RL_EPISODES == {"dqn": presets.RL_BOOK.episodes_dqn, "mbpo": presets.RL_BOOK.episodes_mbpo}


def test_epsilon_reaches_its_floor_after_20_dqn_and_10_mbpo_episodes_of_the_books_budgets():
    """The exploration schedule is a fraction of the whole budget: a budget changed without its fraction would
    change how long the agents explore (and every run of the defaults, not only the long ones)."""
    from softpend.rl.dqn import build_dqn
    from softpend.rl.training_env import make_training_env

    for algo, floor_episode in (("dqn", 20), ("mbpo", 10)):
        config, episodes = figure_configs()[algo], presets.RL_EPISODES[algo]
        schedule = build_dqn(config, make_training_env(config), seed=0, episodes=episodes).exploration_schedule
        epsilon = [schedule(1 - episode / episodes) for episode in range(episodes + 1)]  # SB3's progress_remaining
        floor = [e for e, value in enumerate(epsilon) if abs(value - config.learner.exploration_final_eps) < 1e-9]
        assert floor[0] == floor_episode, algo


def test_figure_configs_take_task_and_rl_overrides():
    """An RL override reaches each config that has the field; a name neither config has is an error."""
    import pytest

    configs = figure_configs("beam", {"rod.torque_limit_nm": 0.08}, {"episode_s": 1.0, "rollout.per_real_step": 3})
    assert configs["dqn"] == presets.load_hparams(
        "dqn", presets.TASK.replace(plant="beam", torque_limit_nm=0.08), {"episode_s": 1.0}
    )
    assert configs["mbpo"].rollout.per_real_step == 3 and configs["mbpo"].episode_s == 1.0
    with pytest.raises(ValueError, match="'rollout_per_real_step' is not a DQNConfig or MBPOConfig field"):
        figure_configs(rl_overrides={"rollout_per_real_step": 3})

"""Expensive: the default DQN (and DQN-MBPO) configs train controllers that swing the rod up and balance it.

Run with ``make test-expensive`` (or ``pytest -m expensive tests/test_rl_balance_expensive.py``); each takes
several minutes on two cores.
"""

import math

import pytest

from softpend.evaluation import SUCCESS_STD_RAD
from softpend.rl.dqn import evaluate_agent, load_agent, train_dqn
from softpend.rl.mbpo import train_mbpo
from softpend.study.presets import load_hparams


def _balances(agent, config) -> None:
    summary = evaluate_agent(agent, config, seeds=(10, 11, 12), duration_s=10.0)
    for result in summary.results:
        assert math.isfinite(result.swing_up_time_s), f"seed {result.seed} never swung up"
        assert result.upright_std_rad <= SUCCESS_STD_RAD, f"seed {result.seed}: std {result.upright_std_rad:.3f} rad"


@pytest.mark.expensive
def test_dqn_learns_to_swing_up_and_balance(tmp_path):
    config = load_hparams("dqn")
    agent, log = train_dqn(config, seed=0, episodes=100, run_dir=tmp_path, progress=False)
    assert math.isfinite(log.real_s_to_balance())
    _balances(agent, config)


@pytest.mark.expensive
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_mbpo_learns_to_swing_up_and_balance(tmp_path, seed):
    # the target is every seed (the book's runs: 65 / 85 / 75 plant s to balance)
    config = load_hparams("mbpo")
    _, log = train_mbpo(config, seed=seed, episodes=50, run_dir=tmp_path, progress=False)
    assert math.isfinite(log.real_s_to_balance())
    # the agent of the best periodic evaluation (seeds 1000, 1001), as the book's figures use it, checked on
    # other start seeds (the final agent may have collapsed again after balancing)
    agent, _ = load_agent(tmp_path)
    _balances(agent, config)

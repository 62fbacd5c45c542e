"""Domain randomisation from an identification's uncertainty: the rods drawn at each training reset (DQN, DQN-MBPO)
and each PILCO trial follow the relative standard deviations; by default nothing is drawn."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from softpend.envs.randomised import RandomisedRod, RodUncertainty
from softpend.plant import RodParams
from softpend.rl.config import DQNConfig, config_to_dict, load_config, save_config
from softpend.rl.training_env import make_training_env

#: A hand-made uncertainty: the hub inertia known to 10 %, the tip mass exactly, two deviations wide.
UNCERTAINTY = RodUncertainty((("hub_inertia_kgm2", 0.1), ("tip_mass_kg", 0.0)), scale=2.0)


def _inner_rods(env, resets: int, seed: int) -> list[RodParams]:
    rods = []
    for i in range(resets):
        env.reset(seed=seed if i == 0 else None)
        rods.append(env.unwrapped.params)
        assert env.unwrapped.plant.params == env.unwrapped.params  # the plant itself was rebuilt
    return rods


def test_each_training_reset_draws_a_rod_within_the_uncertainty():
    config = DQNConfig(episode_s=1.0, rod_uncertainty=UNCERTAINTY)
    env = make_training_env(config)
    assert any(isinstance(e, RandomisedRod) for e in _wrappers(env))
    rods = _inner_rods(env, 200, seed=3)
    base = config.task.rod
    log_ratio = np.log([r.hub_inertia_kgm2 / base.hub_inertia_kgm2 for r in rods])
    assert np.all(np.abs(log_ratio) <= 0.2 + 1e-12) and np.abs(log_ratio).max() > 0.18  # fills exp(+-2 x 0.1)
    assert len(set(log_ratio)) == 200  # a fresh rod every episode
    assert all(r.tip_mass_kg == base.tip_mass_kg for r in rods)  # relative std 0: never changes
    assert all(r.youngs_modulus_pa == base.youngs_modulus_pa for r in rods)  # not uncertain: held
    assert _inner_rods(make_training_env(config), 200, seed=3) == rods  # the run's own seed stream
    assert _inner_rods(make_training_env(config), 5, seed=4) != rods[:5]


def _wrappers(env):
    while hasattr(env, "env"):
        yield env
        env = env.env


def test_by_default_nothing_is_drawn_and_the_saved_config_is_unchanged(tmp_path):
    config = DQNConfig(episode_s=1.0)
    assert config.rod_uncertainty is None and "rod_uncertainty" not in config_to_dict(config)
    env = make_training_env(config)
    assert not any(isinstance(e, RandomisedRod) for e in _wrappers(env))
    assert all(r == config.task.rod for r in _inner_rods(env, 5, seed=0))
    save_config(config, tmp_path / "plain.json")
    assert load_config(tmp_path / "plain.json") == config
    randomised = dataclasses.replace(config, rod_uncertainty=UNCERTAINTY)
    save_config(randomised, tmp_path / "randomised.json")
    assert load_config(tmp_path / "randomised.json") == randomised  # a changed uncertainty is another run


def test_each_pilco_trial_runs_on_a_drawn_rod():
    from softpend.pilco.loop import Pilco, PilcoConfig

    settings = {"horizon_s": 1.0, "eval_seeds": (), "gp": dataclasses.replace(PilcoConfig().gp, max_points=20)}
    plain = Pilco(PilcoConfig(**settings))
    plain.random_trial()
    assert plain.env.params == plain.config.task.rod
    config = PilcoConfig(**settings, rod_uncertainty=UNCERTAINTY)
    assert PilcoConfig.from_dict(config.to_dict()) == config
    assert "rod_uncertainty" not in PilcoConfig(**settings).to_dict()
    pilco = Pilco(config)
    rods = []
    for _ in range(3):
        pilco.random_trial()
        rods.append(pilco.env.params)
    base = config.task.rod
    assert len({r.hub_inertia_kgm2 for r in rods}) == 3
    assert all(abs(np.log(r.hub_inertia_kgm2 / base.hub_inertia_kgm2)) <= 0.2 + 1e-12 for r in rods)
    assert all(r.tip_mass_kg == base.tip_mass_kg for r in rods)
    assert pilco.records[0].real_cost != plain.records[0].real_cost  # the trial ran on the drawn rod


def test_bad_uncertainties_are_refused_by_name():
    for relative_std, name in ((("no_field", 0.1),), "no_field"), ((("tip_mass_kg", -0.1),), "tip_mass_kg"):
        with pytest.raises(ValueError, match=name):
            RodUncertainty(relative_std)
    with pytest.raises(ValueError, match="scale"):
        RodUncertainty((), scale=0.0)
    with pytest.raises(ValueError, match="rod_uncertainty"):
        DQNConfig(rod_uncertainty={"relative_std": [1, 2]})
    assert DQNConfig(rod_uncertainty=UNCERTAINTY.to_dict()).rod_uncertainty == UNCERTAINTY

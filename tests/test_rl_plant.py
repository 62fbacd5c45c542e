"""The RL figures' `plant` parameter: agents train and are evaluated on the named true plant, and runs on
different plants never share a run folder."""

from pathlib import Path

import pytest

from softpend.plant.beam import BeamPlant
from softpend.rl.config import DQNConfig, MBPOConfig
from softpend.rl.dqn import load_agent, train_dqn
from softpend.rl.training_env import make_training_env
from softpend.study.presets import load_hparams
from softpend.study.rl_runs import figure_configs, figure_runs, plant_runs_root, run_folder
from softpend.task import Task


def test_plant_is_validated_with_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="plant"):
        DQNConfig(task=Task(plant="rigid"))
    with pytest.raises(ValueError, match="plant"):
        figure_configs(plant="Beam")
    with pytest.raises(ValueError, match="plant"):
        figure_runs(1, 1, [0], tmp_path / "runs", progress=False, plant="spring")
    assert not (tmp_path / "runs").exists()  # nothing trained before the check


def test_runs_of_different_plants_live_in_different_folders():
    assert plant_runs_root("runs/rl-book", "prb") == Path("runs/rl-book")
    beam = plant_runs_root("runs/rl-book", "beam")
    assert beam == Path("runs/rl-book-beam")
    assert run_folder(beam, "dqn", 0) != run_folder("runs/rl-book", "dqn", 0)
    configs = figure_configs(plant="beam")
    assert configs["dqn"].task.plant == "beam" and isinstance(configs["mbpo"], MBPOConfig)
    assert configs["mbpo"].task.plant == "beam"
    assert figure_configs()["dqn"] == load_hparams("dqn")  # the book's settings on the PRB plant


def test_dqn_trains_and_evaluates_on_the_beam(tmp_path):
    config = DQNConfig(
        task=Task(plant="beam"),
        episode_s=0.4,
        learning_starts=5,
        eval_every_episodes=1,
        checkpoint_every_episodes=1,
        eval_seeds=(0,),
        eval_duration_s=0.3,
    )
    assert isinstance(make_training_env(config).unwrapped.plant, BeamPlant)
    _, log = train_dqn(config, seed=0, episodes=1, run_dir=tmp_path, progress=False)
    assert log.plant_s == pytest.approx(0.4) and len(log.evaluations) == 1
    _, loaded = load_agent(tmp_path)
    assert loaded.task.plant == "beam"
    # the beam rod, unlike the 4-link PRB chain, has no 4-link joint state: the evaluation ran on the beam
    from softpend.rl.dqn import evaluate_agent

    agent, _ = load_agent(tmp_path)
    result = evaluate_agent(agent, loaded, seeds=(0,), duration_s=0.2).results[0]
    assert result.joint_angles_rad.shape[1] == BeamPlant(dt_s=0.01).n_coordinates != 5

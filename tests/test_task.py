"""The Task object: validation, copies, round trips, and that every consumer builds the same plant from it."""

import json

import numpy as np
import pytest

from softpend.envs import SoftPendulumEnv
from softpend.evaluation import evaluate_controller
from softpend.pilco import PilcoConfig
from softpend.plant import PRBPlant, RodParams
from softpend.plant.beam import BeamPlant
from softpend.rl.config import DQNConfig, MBPOConfig, load_config, save_config
from softpend.rl.training_env import make_base_env
from softpend.task import Task


def as_controller(function):
    """A plain function ``f(observation, q, q_dot, time_s) -> torque_nm`` as a controller."""
    function.reset = lambda: None
    return function


@pytest.mark.parametrize(
    "changes, match",
    [
        ({"plant": "rubber"}, "task.plant"),
        ({"rod": {"length_m": 0.3}}, "task.rod"),
        ({"dt_s": 0.0}, "task.dt_s"),
        ({"dt_s": float("nan")}, "task.dt_s"),
        ({"dt_s": True}, "task.dt_s"),
        ({"substeps": 0}, "task.substeps"),
        ({"substeps": 2.5}, "task.substeps"),
        ({"start": "sideways"}, "task.start"),
        ({"start_noise_rad": -0.1}, "task.start_noise_rad"),
        ({"start_noise_rad": float("inf")}, "task.start_noise_rad"),
    ],
)
def test_bad_fields_are_named(changes, match):
    with pytest.raises(ValueError, match=match):
        Task(**changes)


def test_replace_reaches_into_the_rod_and_refuses_unknown_names():
    task = Task().replace(torque_limit_nm=0.05, start="upright")
    assert task.rod == RodParams(torque_limit_nm=0.05) and task.start == "upright"
    assert task.torque_limit_nm == 0.05 and Task().torque_limit_nm == RodParams().torque_limit_nm
    with pytest.raises(ValueError, match="unknown Task fields"):
        Task().replace(torque_nm=1.0)
    with pytest.raises(ValueError, match="torque_limit_nm"):
        Task().replace(torque_limit_nm=-1.0)


def test_dict_round_trip_through_json():
    task = Task(plant="beam", dt_s=0.005, substeps=4, start="random", start_noise_rad=0.1).replace(mass_kg=0.07)
    again = Task.from_dict(json.loads(json.dumps(task.to_dict())))
    assert again == task
    with pytest.raises(ValueError, match="unknown Task fields"):
        Task.from_dict({**task.to_dict(), "extra": 1})


def test_the_task_builds_its_plant():
    assert isinstance(Task().make_plant(), PRBPlant)
    beam = Task(plant="beam").make_plant()
    assert isinstance(beam, BeamPlant)
    plant = Task(dt_s=0.02, substeps=3).replace(n_links=2).make_plant()
    assert plant.dt_s == 0.02 and plant.substeps == 3 and plant.n_coordinates == 3


def test_configs_carry_the_task_and_save_it(tmp_path):
    task = Task().replace(n_links=3, torque_limit_nm=0.05)
    for config in (DQNConfig(task=task), MBPOConfig(task=task)):
        save_config(config, tmp_path / "config.json")
        assert load_config(tmp_path / "config.json") == config
    env = make_base_env(DQNConfig(task=task)).unwrapped
    assert env.params == task.rod and env.plant.n_coordinates == 4
    assert PilcoConfig.from_dict(PilcoConfig(task=task).to_dict()).task == task
    with pytest.raises(ValueError, match="task"):
        DQNConfig(task="prb")
    with pytest.raises(ValueError, match="task"):
        PilcoConfig(task=RodParams())


def test_evaluation_runs_on_the_task_it_is_given():
    """The same controller and seed give the same episode through the task as through the environment
    built by hand from the same settings, and a different start distribution gives a different episode."""
    controller = as_controller(lambda o, q, qd, t: 0.03 * np.sin(3 * t))
    task = Task(start_noise_rad=0.1)
    via_task = evaluate_controller(controller, task, seeds=[3], duration_s=0.5).results[0]
    env = SoftPendulumEnv(params=RodParams(), start="hanging", start_noise_rad=0.1)
    from softpend.evaluation import run_episode

    by_hand = run_episode(controller, env, seed=3, duration_s=0.5)
    np.testing.assert_array_equal(via_task.observations, by_hand.observations)
    upright = evaluate_controller(controller, task.replace(start="upright"), seeds=[3], duration_s=0.5).results[0]
    assert abs(upright.theta_rad[0]) < 0.2 < abs(via_task.theta_rad[0])
    with pytest.raises(ValueError, match="task must be a Task"):
        evaluate_controller(controller, RodParams(), seeds=[0], duration_s=0.5)

"""The batched evaluation (many starts at once on the RK4 chain) against the shared single-start evaluation on a
converged Exudyn plant."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch

from softpend.control.lqr import LQRController
from softpend.control.swingup import EnergySwingUpController
from softpend.evaluation import BatchPolicy, evaluate, evaluate_controller
from softpend.plant.params import randomised_rod
from softpend.rl.config import DQNConfig
from softpend.rl.dqn import build_dqn, evaluate_agent, evaluate_agents_batched
from softpend.rl.training_env import make_training_env
from softpend.study.fresh_starts import fresh_start_row
from softpend.task import Task

UPRIGHT = Task(start="upright")
#: The single evaluation's Exudyn plant with enough sub-steps to be close to converged.
CONVERGED = 20


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _wrapped(angle: np.ndarray) -> np.ndarray:
    return np.abs((angle + np.pi) % (2 * np.pi) - np.pi)


def _assert_same_fields(batched, single) -> None:
    for b, s in zip(batched.results, single.results):
        assert b.seed == s.seed
        assert b.time_s.shape == s.time_s.shape and b.observations.shape == s.observations.shape
        assert b.joint_angles_rad.shape == s.joint_angles_rad.shape and b.torque_nm.shape == s.torque_nm.shape
        np.testing.assert_array_equal(b.time_s, s.time_s)
        assert b.diverged is None and s.diverged is None


@pytest.fixture(scope="module")
def agent():
    config = DQNConfig(episode_s=0.4, learning_starts=5, eval_seeds=(7,), eval_duration_s=0.3)
    torch.set_num_threads(1)
    return build_dqn(config, make_training_env(config), seed=3, episodes=1), config


def test_lqr_from_seeded_upright_starts_matches_the_single_evaluation() -> None:
    lqr = LQRController.from_params(UPRIGHT.rod, dt_s=UPRIGHT.dt_s)
    seeds = (11, 3, 7)  # any list of seeds: each rod seeded with its own
    batched = evaluate(lqr, UPRIGHT, engine="batched", seeds=seeds, duration_s=2.0)
    single = evaluate_controller(lqr, UPRIGHT.replace(substeps=CONVERGED), seeds=seeds, duration_s=2.0)
    _assert_same_fields(batched, single)
    starts = [r.observations[0] for r in single.results]
    assert np.ptp([s[0] for s in starts]) > 0.01  # the seeds drew different start tilts
    for b, s in zip(batched.results, single.results):
        np.testing.assert_allclose(b.observations[0], s.observations[0], atol=1e-9)  # the same start (measured: equal)
        assert b.success and s.success
        assert b.swing_up_time_s == s.swing_up_time_s
        assert np.max(np.abs(b.theta_rad - s.theta_rad)) < 5e-5  # measured 1.5e-5 to 2.2e-5 rad
        assert np.max(np.abs(b.torque_nm - s.torque_nm)) < 5e-4  # measured 2.2e-4 N m, of a 0.06 N m limit
        assert abs(b.upright_std_rad - s.upright_std_rad) < 1e-5


def test_lqr_from_a_tilt_and_on_perturbed_rods_matches_the_single_evaluation() -> None:
    lqr = LQRController.from_params(UPRIGHT.rod, dt_s=UPRIGHT.dt_s)
    tilt = UPRIGHT.tilt_state(0.2)
    seeds = (0, 1)
    batched = evaluate(lqr, UPRIGHT, engine="batched", seeds=seeds, duration_s=2.0, initial_state=tilt, rod_spread=0.15)
    for seed, b in zip(seeds, batched.results):
        rod = randomised_rod(UPRIGHT.rod, np.random.default_rng(seed), 0.15)  # perturbed_rod_row's rod of this seed
        (s,) = evaluate_controller(
            lqr, UPRIGHT.replace(rod=rod, substeps=CONVERGED), seeds=(seed,), duration_s=2.0, initial_state=tilt
        ).results
        np.testing.assert_allclose(b.joint_angles_rad[0], tilt[0])
        assert b.success == s.success
        assert np.max(np.abs(b.theta_rad - s.theta_rad)) < 1e-4
        assert np.max(np.abs(b.torque_nm)) <= rod.torque_limit_nm + 1e-12


@pytest.mark.filterwarnings("ignore:The call to SystemContainer:DeprecationWarning")  # copying an Exudyn plant
def test_energy_swing_up_matches_the_single_evaluation() -> None:
    """The bang-bang pumping switches a step earlier or later on any two plants (the Exudyn plant at 20 and at 100
    sub-steps differ by 0.11 rad during the swing), so the trajectories agree to 0.1 rad, the outcome exactly."""
    task = Task()
    seeds = (5, 2)
    controllers = [EnergySwingUpController(task.rod, dt_s=task.dt_s) for _ in seeds]  # holds an Exudyn plant: one each
    batched = evaluate(controllers, task, engine="batched", seeds=seeds, duration_s=4.5)
    single = evaluate_controller(
        EnergySwingUpController(task.rod, dt_s=task.dt_s), task.replace(substeps=CONVERGED), seeds=seeds, duration_s=4.5
    )
    _assert_same_fields(batched, single)
    for b, s in zip(batched.results, single.results):
        assert b.success and s.success
        assert abs(b.swing_up_time_s - s.swing_up_time_s) <= 0.02  # measured 0 and 0.01 s
        assert np.max(_wrapped(b.theta_rad - s.theta_rad)) < 0.1  # measured 0.03 and 0.04 rad
        assert abs(b.upright_std_rad - s.upright_std_rad) < 0.01  # measured 0.005 rad (of 0.02-0.025: the catch)
    assert fresh_start_row(batched)["starts"] == 2
    with pytest.raises(ValueError, match="one controller per seed"):
        evaluate(controllers[0], task, engine="batched", seeds=seeds, duration_s=1.0)


def test_dqn_agent_matches_evaluate_agent(agent) -> None:
    model, config = agent
    seeds = (20_000, 20_001, 20_002)
    (batched,) = evaluate_agents_batched([model], config, seeds, 3.0)
    converged = dataclasses.replace(config, task=config.task.replace(substeps=CONVERGED))
    single = evaluate_agent(model, converged, seeds, 3.0)
    _assert_same_fields(batched, single)
    for b, s in zip(batched.results, single.results):
        assert b.success == s.success
        np.testing.assert_array_equal(b.torque_nm, s.torque_nm)  # the same greedy actions, held alike
        assert np.max(np.abs(b.theta_rad - s.theta_rad)) < 5e-5  # measured 1.1e-5 rad
    assert any(np.ptp(r.torque_nm) > 0 for r in batched.results)  # the agent switched torques
    row, expected = fresh_start_row(batched), fresh_start_row(single)
    assert (row["starts"], row["balanced_starts"], row["success_rate"]) == (
        3,
        expected["balanced_starts"],
        expected["success_rate"],
    )


def test_batched_episodes_do_not_depend_on_each_other(agent) -> None:
    model, config = agent
    seeds = (4, 9, 2)
    together = evaluate_agents_batched([model], config, seeds, 1.0)[0].results
    for seed, joint in zip(seeds, together):
        (alone,) = evaluate_agents_batched([model], config, (seed,), 1.0)[0].results
        np.testing.assert_allclose(joint.observations, alone.observations, rtol=0, atol=1e-12)  # measured: equal
        np.testing.assert_array_equal(joint.torque_nm, alone.torque_nm)
        assert joint.metrics() == pytest.approx(alone.metrics())


def test_agents_evaluated_in_one_batch_equal_their_own_evaluations(agent) -> None:
    model, config = agent
    other = build_dqn(config, make_training_env(config), seed=4, episodes=1)  # another network
    with torch.no_grad():  # whose Q-values are turned upside down: its greedy actions differ wherever the Q-values do
        for parameter in list(other.q_net.parameters())[-2:]:
            parameter.neg_()
    seeds = (20_003, 20_004)
    together = evaluate_agents_batched([model, other, model], config, seeds, 1.5)
    assert [len(summary.results) for summary in together] == [2, 2, 2]
    for summary, alone in zip(
        together, [evaluate_agents_batched([m], config, seeds, 1.5)[0] for m in (model, other, model)]
    ):
        for joint, own in zip(summary.results, alone.results):
            assert joint.seed == own.seed
            np.testing.assert_array_equal(joint.observations, own.observations)
            np.testing.assert_array_equal(joint.torque_nm, own.torque_nm)
    assert not all(np.array_equal(a.torque_nm, b.torque_nm) for a, b in zip(together[0].results, together[1].results))
    with pytest.raises(ValueError, match="models must not be empty"):
        evaluate_agents_batched([], config, seeds, 1.0)


def test_a_diverging_rod_is_reported_and_the_others_run_on() -> None:
    lqr = LQRController.from_params(UPRIGHT.rod, dt_s=UPRIGHT.dt_s)
    q, q_dot = UPRIGHT.tilt_state(0.1)
    q_dot = np.stack([q_dot, q_dot + 1e7])  # far beyond what RK4 integrates stably at this step: rod 1 diverges
    summary = evaluate(lqr, UPRIGHT, engine="batched", seeds=(0, 1), duration_s=1.0, initial_state=(q, q_dot))
    ok, bad = summary.results
    assert ok.diverged is None and ok.success and len(ok.time_s) == 101
    assert bad.diverged is not None and "diverged" in bad.diverged and not bad.success
    for r in summary.results:
        for values in (r.observations, r.torque_nm, r.joint_angles_rad):
            assert np.all(np.isfinite(values))
        assert all(not isinstance(v, float) or not math.isnan(v) for v in r.metrics().values())
    (alone,) = evaluate(lqr, UPRIGHT, engine="batched", seeds=(0,), duration_s=1.0, initial_state=(q, q_dot[0])).results
    np.testing.assert_allclose(ok.observations, alone.observations, rtol=0, atol=1e-12)


def evaluate_batched(predict, task, seeds, duration_s, action_repeat=1, n_torque_levels=None, **options):
    policy = BatchPolicy(predict, action_repeat, n_torque_levels)
    return evaluate(policy, task, engine="batched", seeds=seeds, duration_s=duration_s, **options)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"seeds": ()}, "seeds"),
        ({"seeds": (0, -1)}, "seeds"),
        ({"duration_s": -1.0}, "duration_s"),
        ({"duration_s": 0.01}, "duration_s"),
        ({"action_repeat": 0}, "action_repeat"),
        ({"rod_spread": 1.0}, "rod_spread"),
        ({"rod_seed": -2}, "rod_seed"),
        ({"substeps": 1}, "substeps"),
        ({"task": Task(plant="beam")}, "task.plant"),
        ({"n_torque_levels": 1}, "n_torque_levels"),
        ({"initial_state": (np.zeros(3), np.zeros(3))}, r"options\['q'\] must have shape"),
        ({"initial_state": np.zeros(5)}, "initial_state must be a pair"),
        ({"seeds": tuple(range(100_000)), "duration_s": 1e4}, "GiB"),
    ],
)
def test_bad_input_is_refused_naming_it(kwargs, match) -> None:
    args = {"task": Task(), "seeds": (0,), "duration_s": 1.0, **kwargs}
    with pytest.raises(ValueError, match=match):
        evaluate_batched(lambda v: np.zeros((len(v), 1)), **args)


def test_bad_actions_are_refused() -> None:
    with pytest.raises(ValueError, match="actions"):
        evaluate_batched(lambda v: np.zeros(len(v) + 1), Task(), (0, 1), 0.5, n_torque_levels=5)
    with pytest.raises(ValueError, match="predict_batch"):
        evaluate_batched(None, Task(), (0,), 0.5)

"""PILCO's exploration aids: the held random-torque first trial and the screened random policy starts."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from softpend.envs import SoftPendulumEnv
from softpend.evaluation import run_episode
from softpend.pilco import PilcoConfig, RBFPolicy, RandomTorqueController, state_spec
from softpend.pilco.gp import MultiOutputGP
from softpend.pilco.loop import _optimise_policy
from softpend.pilco.propagation import Propagator
from softpend.plant import OBSERVATION_NAMES, Observation

torch.set_num_threads(1)
LIMIT_NM = 0.06


def _torques(controller: RandomTorqueController, n_periods: int) -> np.ndarray:
    controller.reset()
    obs = Observation(*np.zeros(len(OBSERVATION_NAMES)))
    return np.array([controller(obs, None, None, k * controller.control_dt_s) for k in range(n_periods)])


def test_random_controller_holds_bang_bang_torques_for_random_whole_periods():
    controller = RandomTorqueController(LIMIT_NM, 0.1, seed=0, hold_s=(0.2, 0.6), bang_bang=True)
    u = _torques(controller, 200)
    assert set(np.round(u / LIMIT_NM, 12)) == {-1.0, 1.0}
    # runs of one drawn torque last 2..6 periods (two equal draws in a row merge into a longer run)
    changes = np.flatnonzero(np.diff(u) != 0) + 1
    runs = np.diff(np.concatenate([[0], changes]))
    assert runs.min() >= 2 and np.median(runs) <= 6 and len(runs) > 15
    np.testing.assert_array_equal(u, _torques(controller, 200))  # reset re-seeds: reproducible
    assert not np.array_equal(u, _torques(RandomTorqueController(LIMIT_NM, 0.1, 1, (0.2, 0.6), True), 200))
    # the default is a new uniform draw every period
    plain = _torques(RandomTorqueController(LIMIT_NM, 0.1, seed=0), 50)
    assert len(np.unique(plain)) == 50 and np.max(np.abs(plain)) <= LIMIT_NM
    with pytest.raises(ValueError, match="hold_s"):
        RandomTorqueController(LIMIT_NM, 0.1, seed=0, hold_s=(0.6, 0.2))
    with pytest.raises(ValueError, match="random_hold_max_s"):
        PilcoConfig(random_hold_min_s=0.6, random_hold_max_s=0.2)


def test_held_random_torques_swing_the_soft_rod_further_than_per_period_draws():
    """Physics: holding the torque for about half a swing pumps energy into the hanging rod."""
    env = SoftPendulumEnv(dt_s=0.01, start="hanging", start_noise_rad=0.05)
    theta = OBSERVATION_NAMES.index("theta_rad")

    def swing_rad(controller: RandomTorqueController, seed: int) -> float:
        episode = run_episode(controller, env, seed=seed, duration_s=4.0)
        return float(np.max(np.pi - np.abs(episode.observations[:, theta])))  # largest angle away from hanging

    held = [swing_rad(RandomTorqueController(LIMIT_NM, 0.1, s, (0.2, 0.6), True), s) for s in range(3)]
    plain = [swing_rad(RandomTorqueController(LIMIT_NM, 0.1, s), s) for s in range(3)]
    assert np.mean(held) > 1.5 * np.mean(plain), (held, plain)
    assert max(held) > np.pi / 2  # at least one random trial takes the tip above the horizontal


def test_policy_search_starts_from_the_best_screened_candidate_and_keeps_the_best_restart():
    spec = state_spec("tip")
    rng = np.random.default_rng(0)
    states = np.column_stack([rng.uniform(-8, 8, 60), rng.uniform(-np.pi, np.pi, 60)])
    u = rng.uniform(-LIMIT_NM, LIMIT_NM, 60)
    # a weak-motor pendulum (theta from upright): 0.1 s differences
    dy = np.column_stack([0.1 * (20.0 * np.sin(states[:, 1]) + 500.0 * u), 0.1 * states[:, 0]])
    gp = MultiOutputGP(np.hstack([spec.model_inputs(states), u[:, None]]), dy)
    m0 = torch.tensor([0.0, 2.0], dtype=torch.float64)
    s0 = 0.05**2 * torch.eye(2, dtype=torch.float64)
    lengthscales = np.array([5.0, 0.7, 0.7])
    n_steps = 8

    def fresh(seed: int, target_std: float) -> RBFPolicy:
        centers = spec.model_inputs(states[np.random.default_rng(seed).choice(60, 8)])
        return RBFPolicy(centers, lengthscales, LIMIT_NM, seed=seed, target_std=target_std)

    def predicted(vector: np.ndarray) -> float:
        policy = fresh(0, 0.1)
        policy.set_vector(vector)
        with torch.no_grad():
            return float(Propagator(spec, gp, policy, 0.3, 0.15).rollout(m0, s0, n_steps)[3])

    candidates = [fresh(s, 1.0).get_vector() for s in range(1, 9)]
    start_costs = [predicted(fresh(0, 0.1).get_vector())] + [predicted(c) for c in candidates]
    assert min(start_costs[1:]) < start_costs[0] - 0.5  # some random full-range policy is far better
    policy = fresh(0, 0.1)
    cost = _optimise_policy(Propagator(spec, gp, policy, 0.3, 0.15), policy, m0, s0, n_steps, iterations=2,
                            candidates=candidates)
    assert cost <= min(start_costs) + 1e-9
    assert predicted(policy.get_vector()) == pytest.approx(cost)
    # a restart (the second-best start) never ends worse than the single search
    restarted = fresh(0, 0.1)
    restarted_cost = _optimise_policy(Propagator(spec, gp, restarted, 0.3, 0.15), restarted, m0, s0, n_steps,
                                      iterations=2, candidates=candidates, restarts=1)
    assert restarted_cost <= cost + 1e-9

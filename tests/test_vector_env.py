"""The vector environment on the batched chain against the single Exudyn environment and Gymnasium's rules."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import data_equivalence

import softpend  # noqa: F401  (registers the environments)
from softpend.envs import SoftPendulumDiscreteEnv, SoftPendulumEnv
from softpend.envs.vector import SoftPendulumDiscreteVectorEnv, SoftPendulumVectorEnv
from softpend.plant import RodParams


def _single_runs(env_class, seeds, actions, **kwargs):
    """Observations and rewards of one single environment per seed, converged Exudyn (200 sub-steps)."""
    observations, rewards = [], []
    for i, seed in enumerate(seeds):
        env = env_class(substeps=200, **kwargs)
        obs, _ = env.reset(seed=seed)
        run, paid = [obs], []
        for action in actions[:, i]:
            obs, reward, terminated, truncated, _ = env.step(action)
            assert not (terminated or truncated)
            run.append(obs)
            paid.append(reward)
        observations.append(run)
        rewards.append(paid)
    return np.array(observations).transpose(1, 0, 2), np.array(rewards).T


@pytest.mark.parametrize("discrete", [False, True])
def test_vector_env_follows_the_single_env_from_the_same_seeds(discrete: bool) -> None:
    rng = np.random.default_rng(0)
    n_steps, seeds = 100, [5, 6, 7]
    kwargs = {"params": RodParams(n_links=4), "start": "random"}
    if discrete:
        actions = rng.integers(0, 5, (n_steps, 3))
        vec = SoftPendulumDiscreteVectorEnv(num_envs=3, substeps=20, **kwargs)
        single_class = SoftPendulumDiscreteEnv
        single_actions = actions
    else:
        actions = rng.uniform(-1, 1, (n_steps, 3, 1)).astype(np.float32)
        vec = SoftPendulumVectorEnv(num_envs=3, substeps=20, **kwargs)
        single_class = SoftPendulumEnv
        single_actions = actions
    expected_obs, expected_rewards = _single_runs(single_class, seeds, single_actions, **kwargs)
    obs, info = vec.reset(seed=5)
    observations, rewards = [obs], []
    for action in actions:
        obs, reward, terminated, truncated, info = vec.step(action)
        assert not terminated.any() and not truncated.any()
        observations.append(obs)
        rewards.append(reward)
    np.testing.assert_allclose(observations[0], expected_obs[0], atol=1e-7)  # the same start draws
    np.testing.assert_allclose(np.array(observations), expected_obs, atol=2e-5)
    np.testing.assert_allclose(np.array(rewards), expected_rewards, atol=2e-4)
    assert np.ptp(expected_obs[:, :, 0]) > 0.5  # the rods swung


def test_rosenbrock_vector_env_follows_the_single_env_to_its_accuracy() -> None:
    """With the Rosenbrock integrator (default two sub-steps) the rods follow the converged single environment
    over 1 s to within the integrator's error (a few 1e-3 rad at n = 4), and n = 10 needs no more sub-steps."""
    rng = np.random.default_rng(1)
    n_steps, seeds = 100, [5, 6]
    kwargs = {"params": RodParams(n_links=4), "start": "random"}
    actions = rng.uniform(-1, 1, (n_steps, 2, 1)).astype(np.float32)
    expected_obs, _ = _single_runs(SoftPendulumEnv, seeds, actions, **kwargs)
    vec = SoftPendulumVectorEnv(num_envs=2, integrator="rosenbrock", **kwargs)
    assert vec.chain.substeps == 2
    observations = [vec.reset(seed=5)[0]] + [vec.step(a)[0] for a in actions]
    error = np.abs(np.array(observations) - expected_obs)[:, :, :2].max()  # the hub and tip angle features
    assert 1e-6 < error < 2e-2, error
    long = SoftPendulumVectorEnv(num_envs=2, params=RodParams(n_links=10), integrator="rosenbrock", substeps=1)
    long.reset(seed=0)
    for action in actions[:50]:
        obs, _, _, truncated, _ = long.step(action)
    assert np.isfinite(obs).all() and not truncated.any()


def test_autoreset_is_next_step_and_keeps_each_generator() -> None:
    """As ``SyncVectorEnv`` over the single environments: the step after truncation returns the reset
    observation with reward 0, drawn from the sub-environment's own generator."""
    kwargs = {"start": "random", "max_episode_steps": 3}
    vec = gym.make_vec("softpend/SoftPendulum-v0", num_envs=2, substeps=10, **kwargs)
    sync = gym.make_vec("softpend/SoftPendulum-v0", num_envs=2, vectorization_mode="sync", substeps=50, **kwargs)
    assert isinstance(vec.unwrapped, SoftPendulumVectorEnv)
    assert vec.metadata["autoreset_mode"] == sync.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
    actions = np.full((2, 1), 0.5, dtype=np.float32)
    v_obs, _ = vec.reset(seed=1)
    s_obs, _ = sync.reset(seed=1)
    np.testing.assert_allclose(v_obs, s_obs, atol=1e-7)
    for step in range(7):
        v_obs, v_rew, v_term, v_trunc, _ = vec.step(actions)
        s_obs, s_rew, s_term, s_trunc, _ = sync.step(actions)
        assert data_equivalence(v_trunc, s_trunc) and data_equivalence(v_term, s_term), step
        np.testing.assert_allclose(v_obs, s_obs, atol=1e-3)
        np.testing.assert_allclose(v_rew, s_rew, atol=1e-2)
        if step == 3:  # the autoreset step: exact reset draws, reward 0
            np.testing.assert_allclose(v_obs, s_obs, atol=1e-7)
            assert np.all(v_rew == 0.0)
    assert v_trunc.tolist() == [True, True]


def test_spaces_dtypes_and_determinism() -> None:
    def run(seed):
        env = SoftPendulumVectorEnv(num_envs=4, start="random")
        env.action_space.seed(seed)
        obs, info = env.reset(seed=seed)
        out = [obs]
        for _ in range(20):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            assert env.observation_space.contains(obs)
            assert reward.shape == (4,) and reward.dtype == np.float64
            assert terminated.dtype == truncated.dtype == np.bool_
            assert info["observation"].shape == (4, 10)
            out.append(obs)
        return np.array(out), env

    first, env = run(3)
    second, _ = run(3)
    third, _ = run(4)
    assert env.single_observation_space == SoftPendulumEnv().observation_space
    assert env.single_action_space == SoftPendulumEnv().action_space
    assert data_equivalence(first, second)
    assert not np.allclose(first, third)


def test_reset_mask_resets_only_the_chosen_rods() -> None:
    env = SoftPendulumVectorEnv(num_envs=3, start="random")
    env.reset(seed=2)
    for _ in range(5):
        moved, *_ = env.step(np.ones((3, 1), dtype=np.float32))
    fresh = SoftPendulumVectorEnv(num_envs=3, start="random")
    start, _ = fresh.reset(seed=[12, 13, 14])
    obs, info = env.reset(seed=[12, None, 14], options={"reset_mask": np.array([True, False, True])})
    np.testing.assert_array_equal(obs[[0, 2]], start[[0, 2]])
    np.testing.assert_array_equal(obs[1], moved[1])
    assert info["_observation"].tolist() == [True, False, True]


def test_make_vec_builds_both_action_spaces() -> None:
    discrete = gym.make_vec("softpend/SoftPendulumDiscrete-v0", num_envs=3, n_torque_levels=7)
    assert isinstance(discrete.unwrapped, SoftPendulumDiscreteVectorEnv)
    assert discrete.single_action_space == gym.spaces.Discrete(7)
    discrete.reset(seed=0)
    _, _, _, _, info = discrete.step(np.array([0, 3, 6]))
    np.testing.assert_allclose(info["torque_nm"], [-0.06, 0.0, 0.06], atol=1e-15)
    assert discrete.unwrapped.max_episode_steps == softpend.MAX_EPISODE_STEPS


@pytest.mark.parametrize(
    "kwargs, name",
    [
        ({"num_envs": 0}, "num_envs"),
        ({"start": "sideways"}, "start"),
        ({"max_episode_steps": 0}, "max_episode_steps"),
        ({"params": RodParams(n_links=10), "substeps": 2}, "substeps"),
    ],
)
def test_bad_arguments_raise_value_error_naming_them(kwargs, name) -> None:
    with pytest.raises(ValueError, match=name):
        SoftPendulumVectorEnv(**kwargs)


def test_bad_actions_raise_value_error() -> None:
    env = SoftPendulumVectorEnv(num_envs=2)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="actions"):
        env.step(np.zeros((3, 1)))
    with pytest.raises(ValueError, match="actions"):
        env.step(np.array([[0.0], [np.nan]]))
    discrete = SoftPendulumDiscreteVectorEnv(num_envs=2)
    discrete.reset(seed=0)
    with pytest.raises(ValueError, match="actions"):
        discrete.step(np.array([0, 5]))
    with pytest.raises(ValueError, match="actions"):
        discrete.step(np.array([0.5, 1.0]))


def test_exact_starts_through_reset_options_follow_the_single_env_and_keep_the_draws() -> None:
    """``options={"q", "q_dot"}`` (one state for every rod, or one per rod) start each rod exactly there, as the
    single environment does with the same options; the masked-out rods and each generator's draws are untouched."""
    q = np.zeros((3, 5))
    q[:, 0] = [0.1, -0.2, 0.3]
    env = SoftPendulumVectorEnv(num_envs=3, substeps=20, start="upright")
    obs, info = env.reset(seed=[4, 5, 6], options={"q": q})
    np.testing.assert_array_equal(env.joint_state()[0].numpy(), q)
    np.testing.assert_array_equal(env.joint_state()[1].numpy(), np.zeros((3, 5)))
    plain = SoftPendulumVectorEnv(num_envs=3, substeps=20, start="upright")
    plain.reset(seed=[4, 5, 6])
    after_plain, _ = plain.reset()  # each generator goes on: the same next starts if both drew alike
    twin = SoftPendulumVectorEnv(num_envs=3, substeps=20, start="upright")
    twin.reset(seed=[4, 5, 6], options={"q": q})
    np.testing.assert_array_equal(twin.reset()[0], after_plain)
    actions = np.full((3, 1), 0.4)
    for _ in range(40):
        stepped, *_ = env.step(actions)
    for i in range(3):  # each rod as the converged single environment runs it from the same exact start
        single = SoftPendulumEnv(substeps=200, start="upright")
        single_obs, _ = single.reset(seed=0, options={"q": q[i]})
        np.testing.assert_allclose(obs[i], single_obs, atol=1e-7)
        for _ in range(40):
            single_obs, *_ = single.step(actions[i])
        np.testing.assert_allclose(stepped[i], single_obs, atol=2e-5)
    one = env.reset(seed=[1, 2, 3], options={"q": q[1], "reset_mask": np.array([False, True, False])})[0]
    np.testing.assert_array_equal(env.joint_state()[0].numpy()[1], q[1])
    np.testing.assert_array_equal(one[[0, 2]], stepped[[0, 2]])


@pytest.mark.parametrize(
    ("options", "match"),
    [
        ({"seed": 3}, r"unknown reset option\(s\) \['seed'\]"),
        ({"q": np.zeros((2, 5))}, r"options\['q'\] must have shape \(5,\) or \(3, 5\), got \(2, 5\)"),
        ({"q": np.zeros(5), "q_dot": np.full(5, np.inf)}, r"options\['q_dot'\] must be finite"),
        ({"start": "sideways"}, r"options\['start'\] must be one of"),
    ],
)
def test_bad_reset_options_are_refused_in_one_line(options: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match) as error:
        SoftPendulumVectorEnv(num_envs=3).reset(seed=0, options=options)
    assert "\n" not in str(error.value)

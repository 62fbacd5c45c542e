"""The plant benchmark's legacy step path (kept for the speed-up ratio) gives the same numbers as today's."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import softpend  # noqa: F401  (registers the environments)
from softpend.plant import RodParams
from softpend.study.bench.plant import make_legacy


@pytest.mark.parametrize("n_links", [2, 4])
def test_legacy_and_current_step_paths_give_identical_numbers(n_links: int) -> None:
    runs = []
    for legacy in (False, True):
        env = gym.make("softpend/SoftPendulum-v0", params=RodParams(n_links=n_links), start="random")
        if legacy:
            make_legacy(env)
        obs, _ = env.reset(seed=4)
        rng = np.random.default_rng(2)
        rows = [obs]
        for _ in range(300):
            obs, reward, _, _, _ = env.step(rng.uniform(-1, 1, 1).astype(np.float32))
            rows.append(np.append(obs, reward))
        q, qd = env.unwrapped.plant.joint_state()
        runs.append((np.concatenate([np.ravel(r) for r in rows]), q, qd))
    for current, old in zip(runs[0], runs[1]):
        assert np.array_equal(current, old)

"""One pool for every method's runs (softpend.study.run_pool): the same runs as each method's own pool, in
their own folders, PILCO's started first and DQN's last, and nothing trained twice."""

from __future__ import annotations

import dataclasses
import json

import pytest

from softpend.pilco.loop import PilcoConfig
from softpend.rl.config import DQNConfig, MBPOConfig
from softpend.study import run_pool
from softpend.study.head_to_head import pilco_runs
from softpend.study.rl_runs import train_seeds
from softpend.study.run_pool import book_run_jobs, book_run_names, train_book_runs, train_in_one_pool

TINY_DQN = DQNConfig(learning_starts=20, episode_s=1.0, eval_every_episodes=2, checkpoint_every_episodes=2,
                     eval_seeds=(0,), eval_duration_s=1.0)
TINY_PILCO = PilcoConfig(n_policy_trials=0, horizon_s=1.0, prediction_s=None)


def records(result) -> str:
    """A PILCO run's trial records without their timings (JSON text: NaN equals NaN)."""
    return json.dumps([{k: v for k, v in dataclasses.asdict(r).items() if k not in ("wall_s_total", "cpu_s_total")}
                       for r in result.records])


def numbers(log):
    return [{k: v for k, v in row.items() if k not in ("wall_s", "cpu_s")} for row in log.episodes + log.evaluations]


def test_one_pool_trains_the_runs_each_method_trains_on_its_own(tmp_path):
    pool, here = tmp_path / "pool", tmp_path / "here"
    assert train_in_one_pool([("dqn", TINY_DQN, [0, 1], 2)], pool, TINY_PILCO, [0], pool / "pilco", workers=2,
                             progress=False) == 3
    assert train_in_one_pool([("dqn", TINY_DQN, [0, 1], 2)], pool, TINY_PILCO, [0], pool / "pilco", workers=2,
                             progress=False) == 0  # finished runs are kept
    stamp = (pool / "dqn-seed0" / "log.json").stat().st_mtime_ns
    from_pool = train_seeds("dqn", TINY_DQN, [0, 1], 2, pool, progress=False, workers=1)  # found, not trained
    assert (pool / "dqn-seed0" / "log.json").stat().st_mtime_ns == stamp
    own = train_seeds("dqn", TINY_DQN, [0, 1], 2, here, progress=False, workers=1)
    assert [numbers(log) for log in from_pool] == [numbers(log) for log in own]
    assert numbers(own[0]) != numbers(own[1])
    [pilco_pool] = pilco_runs(TINY_PILCO, [0], pool / "pilco", progress=False, workers=1)
    [pilco_own] = pilco_runs(TINY_PILCO, [0], here / "pilco", progress=False, workers=1)
    assert pilco_pool.config == pilco_own.config
    assert records(pilco_pool) == records(pilco_own)


def test_pilco_starts_first_then_dqn_mbpo_then_dqn(tmp_path, monkeypatch):
    started = []
    monkeypatch.setattr(run_pool, "run_jobs", lambda job, jobs, names, *args, **kwargs: started.extend(names))
    mbpo = MBPOConfig(episode_s=1.0)
    train_in_one_pool([("dqn", TINY_DQN, [0, 1], 2), ("mbpo", mbpo, [0], 2)], tmp_path, TINY_PILCO, [3, 4])
    assert started == ["pilco-seed3", "pilco-seed4", "mbpo-seed0", "dqn-seed0", "dqn-seed1"]
    started.clear()
    assert train_book_runs(["rl"], root=tmp_path) == 20  # the book's ten seeds of each RL method, no PILCO
    assert started[:10] == [f"mbpo-seed{k}" for k in range(10)] and started[10:] == [f"dqn-seed{k}" for k in range(10)]
    started.clear()
    assert train_book_runs(["pilco"], root=tmp_path) == 10 and started == [f"pilco-seed{k}" for k in range(10)]
    try:
        train_book_runs(["ppo"], root=tmp_path)
    except ValueError as exc:
        assert "run_sets must be among" in str(exc)
    else:
        raise AssertionError("an unknown run set was accepted")


def test_the_first_seed_set_names_its_three_runs(tmp_path):
    names = [name for name, _ in book_run_jobs(["rl", "pilco", "first_seed"], tmp_path)]
    assert len(names) == len(set(names)) == 30  # the first seed's runs are trained once
    assert names[:10] == [f"pilco-seed{k}" for k in range(10)]
    assert [name for name, _ in book_run_jobs(["first_seed"], tmp_path)] == ["pilco-seed0", "mbpo-seed0", "dqn-seed0"]
    assert book_run_names(["first_seed"]) == {"pilco-seed0", "mbpo-seed0", "dqn-seed0"}
    assert book_run_names(["rl", "pilco"]) == set(names)
    with pytest.raises(ValueError, match="run_sets must be among"):
        book_run_names(["ppo"])

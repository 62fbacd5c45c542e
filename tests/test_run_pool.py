"""One pool for every method's runs (softpend.study.run_pool): the same runs as each method's own pool, PILCO's
started first and DQN's last; and the runs the book's notebooks read under a profile (``softpend sweep --book``)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from softpend.rl.config import DQNConfig
from softpend.study import run_pool
from softpend.study.rl_runs import run_folder, train_seeds
from softpend.study.run_pool import book_jobs, book_run_jobs, train_in_one_pool


def plain(name: str) -> str:
    """A job or folder name without the hash of its settings (``dqn-1a2b3c4d-seed0`` -> ``dqn-seed0``)."""
    return re.sub(r"-[0-9a-f]{8}-seed", "-seed", name)


TINY_DQN = DQNConfig(
    learning_starts=20,
    episode_s=1.0,
    eval_every_episodes=2,
    checkpoint_every_episodes=2,
    eval_seeds=(0,),
    eval_duration_s=1.0,
)


def test_one_pool_trains_the_runs_each_method_trains_on_its_own(tmp_path):
    import dataclasses

    from softpend.pilco.loop import PilcoConfig
    from softpend.study.head_to_head import pilco_runs

    tiny_pilco = PilcoConfig(n_policy_trials=0, horizon_s=1.0, prediction_s=None)
    pool, here = tmp_path / "pool", tmp_path / "here"
    assert train_in_one_pool([("dqn", TINY_DQN, [0, 1], 2)], pool, tiny_pilco, [0], workers=2, progress=False) == 3
    assert train_in_one_pool([("dqn", TINY_DQN, [0, 1], 2)], pool, tiny_pilco, [0], workers=2, progress=False) == 0
    stamp = (run_folder(pool, "dqn", 0) / "log.json").stat().st_mtime_ns
    from_pool = train_seeds("dqn", TINY_DQN, [0, 1], 2, pool, progress=False, workers=1)  # found, not trained
    assert (run_folder(pool, "dqn", 0) / "log.json").stat().st_mtime_ns == stamp

    def numbers(log):
        return [
            {k: v for k, v in row.items() if k not in ("wall_s", "cpu_s")} for row in log.episodes + log.evaluations
        ]

    own = train_seeds("dqn", TINY_DQN, [0, 1], 2, here, progress=False, workers=1)
    assert [numbers(log) for log in from_pool] == [numbers(log) for log in own] and numbers(own[0]) != numbers(own[1])

    def records(result) -> str:  # without timings; JSON text, where NaN equals NaN
        return json.dumps(
            [
                {k: v for k, v in dataclasses.asdict(r).items() if k not in ("wall_s_total", "cpu_s_total")}
                for r in result.records
            ]
        )

    [pilco_pool] = pilco_runs(tiny_pilco, [0], pool, progress=False, workers=1)
    [pilco_own] = pilco_runs(tiny_pilco, [0], here / "pilco", progress=False, workers=1)
    assert pilco_pool.config == pilco_own.config and records(pilco_pool) == records(pilco_own)


def test_pilco_starts_first_then_dqn_mbpo_then_dqn_and_the_first_seed_set_names_its_three_runs(tmp_path, monkeypatch):
    from softpend.pilco.loop import PilcoConfig
    from softpend.rl.config import MBPOConfig

    started = []
    monkeypatch.setattr(run_pool, "_train", lambda jobs, *args: started.extend(plain(name) for name, _ in jobs))
    train_in_one_pool(
        [("dqn", TINY_DQN, [0, 1], 2), ("mbpo", MBPOConfig(episode_s=1.0), [0], 2)],
        tmp_path,
        PilcoConfig(n_policy_trials=0, horizon_s=1.0),
        [3, 4],
    )
    assert started == ["pilco-seed3", "pilco-seed4", "mbpo-seed0", "dqn-seed0", "dqn-seed1"]
    names = [plain(name) for name, _ in book_run_jobs(["rl", "pilco", "first_seed"], tmp_path)]
    assert len(names) == len(set(names)) == 30  # the first seed's runs are trained once
    assert names[:10] == [f"runs/pilco-book/pilco-seed{k}" for k in range(10)]
    assert names[10:20] == [f"runs/rl-book/mbpo-seed{k}" for k in range(10)]
    assert [plain(name) for name, _ in book_run_jobs(["first_seed"], tmp_path)] == [
        "runs/pilco-book/pilco-seed0",
        "runs/rl-book/mbpo-seed0",
        "runs/rl-book/dqn-seed0",
    ]
    with pytest.raises(ValueError, match="run sets .* must be a list among"):
        book_run_jobs(["ppo"], tmp_path)


def test_a_folder_an_earlier_notebook_reads_is_left_to_it(tmp_path):
    """The rig chapter reads the first seed's runs of Figures 4 and 10 under their roots and budgets: its own
    (default) budget must not train those folders again, finished or not."""
    claimed: set[str] = set()
    figure = book_run_jobs(["rl"], tmp_path, {"seeds": [0], "episodes_dqn": 2, "runs_root": "runs/q"}, claimed)
    assert sorted(plain(name) for name, _ in figure) == ["runs/q/dqn-seed0", "runs/q/mbpo-seed0"]
    assert claimed == {"runs/q/dqn-seed0", "runs/q/mbpo-seed0"}
    rig = book_run_jobs(["first_seed"], tmp_path, {"runs_root": "runs/q", "pilco_runs_root": "runs/p"}, claimed)
    assert [plain(name) for name, _ in rig] == ["runs/p/pilco-seed0"]


def test_a_seed_listed_twice_is_one_run(tmp_path):
    """Two jobs for one folder would train the same run twice, at once, in two workers."""
    jobs = book_run_jobs(["rl", "pilco"], tmp_path, {"seeds": [1, 1, 0], "pilco_seeds": [2, 2], "runs_root": "runs/q"})
    names = [plain(name) for name, _ in jobs]
    assert (
        sorted(names)
        == sorted(set(names))
        == [
            "runs/pilco-book/pilco-seed2",
            "runs/q/dqn-seed0",
            "runs/q/dqn-seed1",
            "runs/q/mbpo-seed0",
            "runs/q/mbpo-seed1",
        ]
    )


def test_the_book_runs_of_a_profile_are_those_its_notebooks_train(tmp_path):
    """``softpend sweep --book --profile quick`` trains the quick runs with the settings Figures 4 and 10 use under
    that profile (so that the notebooks find them finished): each folder once, the first notebook's settings."""
    import dataclasses
    import shutil

    from softpend.study.book import load_profiles
    from softpend.study.presets import load_hparams
    from softpend.study.rl_runs import figure_configs

    repo = Path(__file__).resolve().parents[1]
    for name in ("_toc.yml", "book/profiles.yml"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(repo / name, tmp_path / name)
    shutil.copytree(repo / "notebooks", tmp_path / "notebooks")
    quick = load_profiles(tmp_path / "book" / "profiles.yml")["quick"]
    jobs = {plain(name): job for name, job in book_jobs(tmp_path, "quick")}
    rl, pilco = quick["fig04_learning_curves"], quick["fig10_pilco"]
    assert sorted(jobs) == sorted(
        [f"{pilco['pilco_runs_root']}/pilco-seed{s}" for s in pilco["pilco_seeds"]]
        + [f"{rl['runs_root']}/{m}-seed{s}" for m in ("dqn", "mbpo") for s in rl["seeds"]]
    )
    seed = rl["seeds"][0]
    _, algo, config, _, episodes, folder, _ = jobs[f"{rl['runs_root']}/dqn-seed{seed}"]
    assert config == figure_configs(rl_overrides=rl["rl_overrides"])["dqn"] and config != figure_configs()["dqn"]
    assert (algo, episodes, folder) == (
        "dqn",
        rl["episodes_dqn"],
        run_folder(tmp_path / rl["runs_root"], "dqn", seed, config),
    )
    _, config, folder = jobs[f"{pilco['pilco_runs_root']}/pilco-seed{pilco['pilco_seeds'][0]}"]
    assert config == dataclasses.replace(load_hparams("pilco", overrides=pilco["pilco_overrides"]), seed=0)
    assert folder == run_folder(tmp_path / pilco["pilco_runs_root"], "pilco", 0, config)
    assert len(book_jobs(tmp_path, "full")) == 30
    with pytest.raises(ValueError, match="unknown profile 'nope'"):
        book_jobs(tmp_path, "nope")

"""Runs on the sweep engine (joblib loky): results land on disk, a failing job is named, a worker that dies is
retried, and runs trained through the engine equal the same runs trained in the calling process."""

from __future__ import annotations

import json
import os
import re

import pytest
from sweep_jobs import always_die, die_once, write_pid

from softpend.rl.config import DQNConfig
from softpend.study.rl_runs import run_folder, train_seeds
from softpend.study.sweep import SweepFailed, default_backend, default_workers, run_jobs


def test_jobs_run_in_worker_processes(tmp_path):
    run_jobs(write_pid, [(tmp_path, k) for k in range(4)], [f"job{k}" for k in range(4)], workers=2, progress=False)
    lines = [(tmp_path / f"job{k}.txt").read_text().split() for k in range(4)]
    assert [int(line[0]) for line in lines] == [0, 1, 2, 3]
    pids = {int(line[1]) for line in lines}
    assert os.getpid() not in pids and 1 <= len(pids) <= 2
    assert all(line[2] == "False" for line in lines)  # no per-job bars from the workers


def test_a_failing_job_is_named_and_the_others_keep_their_results(tmp_path):
    with pytest.raises(SweepFailed, match=r"'bad'.*negative value -1") as info:
        run_jobs(write_pid, [(tmp_path, 0), (tmp_path, -1)], ["good", "bad"], workers=2, progress=False)
    assert set(info.value.failures) == {"bad"} and "Traceback" in info.value.failures["bad"]
    assert (tmp_path / "job0.txt").exists()


def test_a_dead_worker_is_retried_and_reported_when_it_keeps_dying(tmp_path):
    # each job kills its worker once; a death can take the other job down with the pool, so two retries
    run_jobs(die_once, [(tmp_path, 1), (tmp_path, 2)], ["one", "two"], workers=2, progress=False, retries=2)
    assert (tmp_path / "job1.txt").exists() and (tmp_path / "job2.txt").exists()
    with pytest.raises(SweepFailed, match="'doomed'") as info:
        run_jobs(
            always_die, [(tmp_path, 3), (tmp_path, 4)], ["doomed", "also doomed"], workers=2, progress=False, retries=1
        )
    assert set(info.value.failures) == {"doomed", "also doomed"}
    assert "worker process died" in info.value.failures["doomed"]


def test_one_worker_runs_in_this_process_and_bad_arguments_are_errors(tmp_path, monkeypatch):
    run_jobs(write_pid, [(tmp_path, 5)], ["only"], workers=1, progress=True)
    assert (tmp_path / "job5.txt").read_text().split()[1:] == [str(os.getpid()), "True"]
    with pytest.raises(ValueError, match="workers must be an integer >= 1"):
        run_jobs(write_pid, [(tmp_path, 1)], ["one"], workers=0)
    with pytest.raises(ValueError, match="backend must be one of"):
        run_jobs(write_pid, [(tmp_path, 1)], ["one"], backend="mpi")
    monkeypatch.setenv("SOFTPEND_WORKERS", "3")
    assert default_workers() == 3
    monkeypatch.setenv("SOFTPEND_WORKERS", "two")
    with pytest.raises(ValueError, match="SOFTPEND_WORKERS must be a positive integer, got 'two'"):
        default_workers()
    monkeypatch.setenv("SOFTPEND_BACKEND", "spark")
    with pytest.raises(ValueError, match="SOFTPEND_BACKEND"):
        default_backend()


@pytest.mark.parametrize("backend", ["loky", "ray", "dask"])
def test_runs_trained_on_the_engine_equal_runs_trained_here(tmp_path, backend):
    if backend == "ray":
        pytest.importorskip("ray", reason="backend 'ray' is tested where Ray is installed")
    if backend == "dask":
        pytest.importorskip("dask.distributed", reason="backend 'dask' is tested where Dask is installed")
    config = DQNConfig(
        learning_starts=20,
        episode_s=1.0,
        eval_every_episodes=2,
        checkpoint_every_episodes=2,
        eval_seeds=(0,),
        eval_duration_s=1.0,
    )
    here = train_seeds("dqn", config, [0, 1], 2, tmp_path / "here", progress=False, workers=1)
    there = train_seeds("dqn", config, [0, 1, 1], 2, tmp_path / "there", progress=False, workers=2, backend=backend)
    assert [log.seed for log in there] == [0, 1, 1]  # a repeated seed is trained once and reported twice
    there = there[:2]

    def numbers(log):
        drop = ("wall_s", "cpu_s")
        return [{k: v for k, v in row.items() if k not in drop} for row in log.episodes + log.evaluations]

    assert [numbers(log) for log in here] == [numbers(log) for log in there]
    assert numbers(here[0]) != numbers(here[1])  # the two seeds differ, so equality above means something
    assert (run_folder(tmp_path / "there", "dqn", 1) / "agent.zip").exists()


def test_the_sweep_command_trains_every_method_per_seed_and_reuses_finished_runs(tmp_path, capsys):
    from softpend.cli import main

    argv = [
        "sweep",
        "--methods",
        "dqn,pilco",
        "--seeds",
        "0-1",
        "--episodes-dqn",
        "1",
        "--pilco-trials",
        "0",
        "--runs-root",
        str(tmp_path),
        "--workers",
        "1",
    ]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["seeds"] == [0, 1] and [r["seed"] for r in out["methods"]["dqn"]["runs"]] == [0, 1]
    assert [r["seed"] for r in out["methods"]["pilco"]["runs"]] == [0, 1]
    # run folders named <algo>-<hash of the settings>-seed<k>
    assert sorted(re.sub(r"-[0-9a-f]{8}-", "-", p.name) for p in tmp_path.iterdir()) == [
        "dqn-seed0",
        "dqn-seed1",
        "pilco-seed0",
        "pilco-seed1",
    ]
    stamp = (run_folder(tmp_path, "dqn", 0) / "log.json").stat().st_mtime_ns
    assert main(argv) == 0  # finished runs are reused, not trained again
    assert (run_folder(tmp_path, "dqn", 0) / "log.json").stat().st_mtime_ns == stamp
    assert json.loads(capsys.readouterr().out)["methods"]["dqn"] == out["methods"]["dqn"]
    for bad in (["--seeds", "3-1"], ["--methods", "dqn,ppo"], ["--seeds", "x"]):
        assert main(["sweep", *bad, "--runs-root", str(tmp_path)]) == 2
        assert "error" in capsys.readouterr().err


def test_the_sweep_command_sets_pilco_fields_for_every_run(tmp_path, capsys):
    from softpend.cli import main
    from softpend.pilco.loop import PilcoResult

    argv = [
        "sweep",
        "--methods",
        "pilco",
        "--seeds",
        "3",
        "--pilco-trials",
        "0",
        "--runs-root",
        str(tmp_path),
        "--workers",
        "1",
        "--pilco-set",
        "horizon_s=1.0",
        "--pilco-set",
        "policy.balance_within_rad=null",
    ]
    assert main(argv) == 0
    capsys.readouterr()
    config = PilcoResult.load(run_folder(tmp_path, "pilco", 3)).config
    assert config.horizon_s == 1.0 and config.policy.balance_within_rad is None and config.seed == 3
    for bad in (
        ["--pilco-set", "no_such_field=1"],
        ["--pilco-set", "policy.balance_within_rad=-1"],
        ["--pilco-set", "x"],
    ):
        assert main(["sweep", "--methods", "pilco", "--seeds", "3", *bad, "--runs-root", str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert "error" in err and "Traceback" not in err


def test_the_sweep_command_sets_rl_fields_for_every_run_of_their_method(tmp_path, capsys):
    from softpend.cli import main
    from softpend.rl.config import load_config

    argv = [
        "sweep",
        "--methods",
        "dqn",
        "--seeds",
        "4",
        "--episodes-dqn",
        "1",
        "--runs-root",
        str(tmp_path),
        "--workers",
        "1",
        "--dqn-set",
        "learner.gradient_steps=3",
        "--dqn-set",
        "eval_seeds=[1000]",
        "--mbpo-set",
        "learner.gradient_steps=30",
    ]
    assert main(argv) == 0
    capsys.readouterr()
    config = load_config(run_folder(tmp_path, "dqn", 4) / "config.json")
    assert config.learner.gradient_steps == 3 and config.eval_seeds == (1000,)  # the MBPO setting is not DQN's
    for bad in (["--mbpo-set", "no_such_field=1"], ["--dqn-set", "learner.gradient_steps=0"], ["--mbpo-set", "x"]):
        assert main(["sweep", "--methods", "dqn", "--seeds", "4", *bad, "--runs-root", str(tmp_path)]) == 2
        err = capsys.readouterr().err
        assert "error" in err and "Traceback" not in err

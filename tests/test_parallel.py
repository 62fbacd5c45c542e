"""Runs in worker processes: results land on disk, a failing job is named, and a run trained in a worker
equals the same run trained in the calling process."""

from __future__ import annotations

from pathlib import Path

import pytest

from softpend.study.parallel import default_workers, run_in_processes
from softpend.rl.config import DQNConfig
from softpend.study.rl_runs import run_folder, train_seeds


def write_pid(folder: Path, value: int, progress: bool = True) -> None:
    import os

    if value < 0:
        raise ValueError(f"negative value {value}")
    (folder / f"job{value}.txt").write_text(f"{value} {os.getpid()} {progress}")


def test_jobs_run_in_worker_processes(tmp_path):
    import os

    run_in_processes(write_pid, [(tmp_path, k) for k in range(4)], [f"job{k}" for k in range(4)], workers=2,
                     progress=False)
    lines = [(tmp_path / f"job{k}.txt").read_text().split() for k in range(4)]
    assert [int(line[0]) for line in lines] == [0, 1, 2, 3]
    pids = {int(line[1]) for line in lines}
    assert os.getpid() not in pids and 1 <= len(pids) <= 2
    assert all(line[2] == "False" for line in lines)  # no per-job bars from the workers


def test_a_failing_job_is_named_and_the_others_keep_their_results(tmp_path):
    with pytest.raises(RuntimeError, match=r"job 'bad'.*negative value -1"):
        run_in_processes(write_pid, [(tmp_path, 0), (tmp_path, -1)], ["good", "bad"], workers=2, progress=False)
    assert (tmp_path / "job0.txt").exists()


def test_one_worker_runs_in_this_process_and_bad_arguments_are_errors(tmp_path, monkeypatch):
    import os

    run_in_processes(write_pid, [(tmp_path, 5)], ["only"], workers=1, progress=True)
    assert (tmp_path / "job5.txt").read_text().split()[1:] == [str(os.getpid()), "True"]
    with pytest.raises(ValueError, match="2 jobs but 1 names"):
        run_in_processes(write_pid, [(tmp_path, 1), (tmp_path, 2)], ["one"])
    with pytest.raises(ValueError, match="workers must be >= 1"):
        run_in_processes(write_pid, [(tmp_path, 1)], ["one"], workers=0)
    monkeypatch.setenv("SOFTPEND_WORKERS", "3")
    assert default_workers() == 3
    monkeypatch.setenv("SOFTPEND_WORKERS", "two")
    with pytest.raises(ValueError, match="SOFTPEND_WORKERS must be a positive integer, got 'two'"):
        default_workers()


def test_runs_trained_in_workers_equal_runs_trained_here(tmp_path):
    config = DQNConfig(learning_starts=20, episode_s=1.0, eval_every_episodes=2, checkpoint_every_episodes=2,
                       eval_seeds=(0,), eval_duration_s=1.0)
    here = train_seeds("dqn", config, [0, 1], 2, tmp_path / "here", progress=False, workers=1)
    there = train_seeds("dqn", config, [0, 1, 1], 2, tmp_path / "there", progress=False, workers=2)
    assert [log.seed for log in there] == [0, 1, 1]  # a repeated seed is trained once and reported twice
    there = there[:2]

    def numbers(log):
        drop = ("wall_s", "cpu_s")
        return [{k: v for k, v in row.items() if k not in drop} for row in log.episodes + log.evaluations]

    assert [numbers(log) for log in here] == [numbers(log) for log in there]
    assert numbers(here[0]) != numbers(here[1])  # the two seeds differ, so equality above means something
    assert (run_folder(tmp_path / "there", "dqn", 1) / "agent.zip").exists()

"""Issue 68: no command replaces a file or a run it did not write, no session outlives its duration, and the
inputs that used to give a silent wrong result are named errors."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from softpend.cli import main
from softpend.hardware import protocol as proto


# ---------------------------------------------------------------------------------------------------- sessions
@pytest.mark.realtime
@pytest.mark.timeout(300)
def test_emulator_ends_at_its_duration_after_a_host_connected_and_left(tmp_path):
    """A host opens the pty, reads a little and closes it without reading further: the STATE frames pile up in
    the pty until it is full.  The emulator drops what does not fit and exits at its duration (before the fix
    it blocked in the write to the full pty and only a signal ended it)."""
    process = subprocess.Popen(
        # 100 STATE frames of about 30 bytes a second fill the pty's 16 KiB in about 6 s; the duration leaves 6 s more
        [sys.executable, "-c", "from softpend.cli import main; main()", "rig", "--duration", "12"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        port = process.stdout.readline().split()[0]
        assert port.startswith("/dev/"), port
        fd = os.open(port, os.O_RDWR | os.O_NOCTTY)
        try:
            os.write(fd, proto.encode_message(proto.MSG_HELLO, 1, (proto.PROTOCOL_VERSION, 7)))  # the device streams
            read = b""
            while len(read) < 64:
                read += os.read(fd, 64)
        finally:
            os.close(fd)
        try:
            rc = process.wait(timeout=240)  # a hang, not a timing: 12 s of duration with ample room
        except subprocess.TimeoutExpired:
            pytest.fail("the emulator did not end at its duration after the host left")
        assert rc == 0, process.stderr.read()
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
        process.stdout.close()
        process.stderr.close()


# ---------------------------------------------------------------------------------------------------- silent garbage
@pytest.mark.parametrize("option", [["--set", "task.rod.torque_limit_nm=1e308"], ["--torque-limit-nm", "1e308"]])
@pytest.mark.parametrize("algo", ["dqn", "pilco"])
def test_train_refuses_a_torque_limit_the_plant_cannot_take(tmp_path, capsys, algo, option):
    """Before: the plant diverged on the first step of every episode, the run trained on 0 plant seconds and the
    command exited 0."""
    out = tmp_path / "run"
    rc = main(["train", "--algo", algo, "--episodes", "1", "--out", str(out), "--no-progress", *option])
    err = capsys.readouterr().err
    assert rc != 0
    assert "torque_limit_nm must be at most" in err
    assert not out.exists()


def test_task_bounds_the_torque_limit_by_the_rod():
    from softpend.task import Task

    assert Task().replace(torque_limit_nm=1.0).torque_limit_nm == 1.0
    with pytest.raises(ValueError, match="torque_limit_nm must be at most"):
        Task().replace(torque_limit_nm=1e308)


def test_babble_refuses_an_empty_or_suffix_only_name(tmp_path, monkeypatch, capsys):
    """Before: ``softpend babble ''`` printed ``.npz`` and wrote the hidden file ``.npz`` (``'.npz'``: ``.npz.npz``)."""
    monkeypatch.chdir(tmp_path)
    for name in ("", ".npz", "   ", "sub/", "sub/.npz"):
        assert main(["babble", name, "--n-trials", "1", "--trial-length-s", "0.1", "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert "dataset" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["", ".pt", ".json"])
def test_fit_model_refuses_an_empty_or_suffix_only_name(tmp_path, monkeypatch, capsys, name):
    monkeypatch.chdir(tmp_path)
    assert main(["fit-model", "data.npz", name]) == 2
    assert "model path" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_sweep_refuses_a_backend_that_is_not_installed_whatever_the_job_count(tmp_path, capsys, monkeypatch):
    """Before: with one job (or none: every run finished) ``--backend ray`` ran in-process without a word."""
    monkeypatch.setitem(sys.modules, "ray", None)  # Ray absent, whether or not this machine has it
    monkeypatch.setitem(sys.modules, "ray.util", None)
    monkeypatch.setitem(sys.modules, "ray.util.joblib", None)
    from softpend.study.sweep import run_jobs

    for jobs in ([], [(1,)], [(1,), (2,)]):
        with pytest.raises(ValueError, match="backend 'ray' needs the ray package"):
            run_jobs(print, jobs, [f"job{i}" for i in range(len(jobs))], workers=1, progress=False, backend="ray")
    argv = [
        "sweep",
        "--methods",
        "pilco",
        "--seeds",
        "0",
        "--pilco-trials",
        "0",
        "--runs-root",
        str(tmp_path),
        "--workers",
        "1",
        "--backend",
        "ray",
    ]
    assert main(argv) == 2
    assert "backend 'ray' needs the ray package" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # refused before any run


# ---------------------------------------------------------------------------------------------------- outputs
MARKERS = "[[0.05, 0.0], [-0.05, 0.0], [0.0, -0.35], [0.1, -0.2]]"

#: Every command that writes files: its arguments (``{d}``: a folder of the test) and the files it writes there.
COMMANDS = {
    "rig": (["rig", "--duration", "0.2", "--truth-log", "{d}/truth.csv"], ["truth.csv"]),
    "rig control": (
        ["rig", "control", "lqr", "--twin", "--out", "{d}", "--duration", "0.2", "--no-progress"],
        ["summary.json", "motor_log.csv", "camera_log.csv", "truth_log.csv"],
    ),
    "rig design": (["rig", "design", "--out", "{d}"], ["rig_design.json", "markers.json", "rig_design.png"]),
    "rig check": (["rig", "check", "--twin", "--out", "{d}/check.json", "--rest-s", "0.2"], ["check.json"]),
    "rig calibrate": (
        ["rig", "calibrate", "--twin", "--markers", MARKERS, "--out", "{d}/cal.json"],
        ["cal.json", "cal.report.json"],
    ),
    "rig babble": (
        ["rig", "babble", "--twin", "--out", "{d}", "--duration", "6", "--trial-length-s", "2", "--no-progress"],
        ["summary.json", "rig_dataset.npz", "motor_log.csv", "truth_log.csv", "camera.avi", "camera.csv"],
    ),
    "babble": (["babble", "{d}/data.npz", "--n-trials", "1", "--trial-length-s", "0.1", "--no-progress"], ["data.npz"]),
    "fit-model": (["fit-model", "{d}/missing.npz", "{d}/model"], ["model.pt", "model.json"]),
    "identify": (["identify", "{d}/missing.npz", "--out", "{d}/identified.json"], ["identified.json"]),
    "track": (["track", "{d}/missing.avi", "--out", "{d}/track.csv"], ["track.csv"]),
}
CASES = [(command, name) for command, (_, names) in COMMANDS.items() for name in names]


def _argv(command: str, folder) -> list[str]:
    return [arg.replace("{d}", str(folder)) for arg in COMMANDS[command][0]]


@pytest.mark.parametrize("command, name", CASES, ids=[f"{c}-{n}" for c, n in CASES])
def test_a_users_file_beside_every_output_is_refused_by_name_and_left_as_it_was(tmp_path, capsys, command, name):
    """Before: ``rig control``, ``rig design``, ``rig check``, ``rig calibrate`` and ``rig babble`` replaced a file of
    an output's name in their --out; ``track`` replaced any --out file.  Every command now checks every file it
    will write before any work and refuses, naming the file, one it did not write."""
    folder = tmp_path / "out"
    folder.mkdir()
    mine = folder / name
    mine.write_bytes(b"the user's own file\n")
    assert main(_argv(command, folder)) == 2
    err = capsys.readouterr().err
    assert name in err and "refusing" in err and "Traceback" not in err
    assert mine.read_bytes() == b"the user's own file\n"
    assert sorted(p.name for p in folder.iterdir()) == [name]  # nothing else written: refused before the work


@pytest.mark.parametrize("command", ["rig design", "rig check", "rig calibrate", "babble"])
def test_a_command_replaces_its_own_outputs_not_the_users_edit_of_them(tmp_path, capsys, command):
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "notes.txt").write_text("the user's notes\n")
    argv = _argv(command, folder)
    assert main(argv) in (0, 1) and main(argv) in (0, 1)  # its own outputs are replaced (1: a check failed)
    first = COMMANDS[command][1][0]
    (folder / first).write_bytes((folder / first).read_bytes() + b" ")  # the user edits an output
    capsys.readouterr()
    assert main(argv) == 2
    assert first in capsys.readouterr().err
    assert (folder / "notes.txt").read_text() == "the user's notes\n"


def test_the_writer_refuses_a_file_planned_after_the_work_and_one_that_appeared_during_it(tmp_path):
    from softpend.io.outputs import Outputs

    outputs = Outputs()
    path = outputs.file(tmp_path / "a.json")
    with pytest.raises(ValueError, match="was not planned"):
        outputs.write_text(tmp_path / "b.json", "{}")
    path.write_text("appeared meanwhile")
    with pytest.raises(ValueError, match="a.json exists and is not a file this command wrote"):
        outputs.write_json(path, {})
    assert path.read_text() == "appeared meanwhile"


# ---------------------------------------------------------------------------------------------------- run folders
TINY = [
    "--episodes",
    "1",
    "--no-progress",
    "--set",
    "episode_s=0.5",
    "--set",
    "eval_seeds=[0]",
    "--set",
    "eval_duration_s=0.2",
    "--set",
    "learning_starts=10",
]


def test_train_refuses_another_runs_folder_and_never_trains_over_a_run(tmp_path, capsys):
    """Before: ``softpend train --out FOLDER`` without --resume retrained into another run's folder (other seed,
    other settings) and replaced its agent.zip, config.json and log.json."""
    folder = tmp_path / "run"
    assert main(["train", "--algo", "dqn", "--out", str(folder), *TINY]) == 0
    saved = {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}
    capsys.readouterr()
    for extra, message in (
        (["--seed", "1"], "holds another run (it differs in seed"),
        (["--set", "learner.gamma=0.9"], "holds another run (it differs in learner.gamma"),
        ([], "already holds this run"),
    ):
        assert main(["train", "--algo", "dqn", "--out", str(folder), *TINY, *extra]) == 2
        err = capsys.readouterr().err
        assert str(folder) in err and message in err
    assert main(["train", "--algo", "dqn", "--out", str(folder), *TINY, "--seed", "1", "--resume"]) == 2
    assert {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()} == saved
    assert main(["train", "--algo", "dqn", "--out", str(folder), *TINY[2:], "--episodes", "2", "--resume"]) == 0


def test_train_pilco_refuses_another_runs_folder(tmp_path, capsys):
    import json

    from softpend.study.presets import load_hparams

    folder = tmp_path / "run"
    folder.mkdir()
    other = {"config": load_hparams("pilco", overrides={"seed": 1}).to_dict()}
    (folder / "pilco.json").write_text(json.dumps(other, default=float))
    assert main(["train", "--algo", "pilco", "--out", str(folder), "--seed", "0"]) == 2
    assert "holds another run (it differs in seed" in capsys.readouterr().err
    same = {"config": load_hparams("pilco", overrides={"seed": 0}).to_dict()}
    (folder / "pilco.json").write_text(json.dumps(same, default=float))
    assert main(["train", "--algo", "pilco", "--out", str(folder), "--seed", "0"]) == 2
    assert "already holds this run" in capsys.readouterr().err


def test_a_sweep_over_a_root_with_runs_of_other_settings_leaves_them_alone(tmp_path, capsys):
    """Before: ``softpend sweep`` over a runs folder that held a run with other settings (its folder was
    ``dqn-seed0`` whatever the settings) retrained into it.  Run folders are now named by their settings' hash."""
    from softpend.study.rl_runs import run_folder

    argv = [
        "sweep",
        "--methods",
        "dqn",
        "--seeds",
        "0",
        "--episodes-dqn",
        "1",
        "--runs-root",
        str(tmp_path),
        "--workers",
        "1",
        "--dqn-set",
        "episode_s=0.5",
        "--dqn-set",
        "eval_seeds=[0]",
        "--dqn-set",
        "eval_duration_s=0.2",
        "--dqn-set",
        "learning_starts=10",
    ]
    assert main(argv) == 0
    [first] = list(tmp_path.iterdir())
    saved = {p.name: p.read_bytes() for p in first.iterdir() if p.is_file()}
    legacy = tmp_path / "dqn-seed0"  # a run of the names before the hashes, with other settings
    legacy.mkdir()
    (legacy / "config.json").write_text('{"class": "DQNConfig", "gamma": 0.5}')
    (legacy / "agent.zip").write_bytes(b"an old agent")
    assert main([*argv, "--dqn-set", "learner.gamma=0.9"]) == 0
    capsys.readouterr()
    assert {p.name: p.read_bytes() for p in first.iterdir() if p.is_file()} == saved
    assert (legacy / "agent.zip").read_bytes() == b"an old agent"
    assert len([p for p in tmp_path.iterdir() if p.name.startswith("dqn-")]) == 3
    with pytest.raises(ValueError, match="different settings"):
        run_folder(tmp_path, "dqn", 0)  # which of the two runs is meant needs the config


@pytest.mark.parametrize("command", sorted(COMMANDS))
def test_an_empty_output_path_is_a_named_error(tmp_path, monkeypatch, capsys, command):
    """Before: ``rig check --out ''`` and ``rig --truth-log ''`` wrote nothing without a word, ``rig control --out ''``
    wrote its logs into the current folder."""
    monkeypatch.chdir(tmp_path)
    argv = ["" if "{d}" in arg and "missing" not in arg else arg.replace("{d}", ".") for arg in COMMANDS[command][0]]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "error" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("algo", ["dqn", "pilco"])
def test_train_refuses_an_empty_run_folder_path(tmp_path, monkeypatch, capsys, algo):
    """Before: ``--out ''`` trained into the current folder."""
    monkeypatch.chdir(tmp_path)
    assert main(["train", "--algo", algo, "--out", "", "--episodes", "1", "--no-progress"]) == 2
    assert "the path is empty" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_log_of_a_run_that_stopped_before_its_end_is_still_the_commands(tmp_path):
    """A crash-safe log is written in place (:meth:`Outputs.live`); a run that died before :meth:`Outputs.done`
    leaves it recorded as being written: the next run may replace that log, never a file put in its place."""
    from softpend.io.outputs import Outputs
    from softpend.io.samplelog import SampleLog

    path = Outputs().file(tmp_path / "motor_log.csv")
    first = Outputs()
    first.file(path)
    with SampleLog(first.live(path), ["t_s"]) as log:
        log.append([0.0])  # ... and the process dies here: no done()
    Outputs().file(path)  # the next run may replace it
    path.unlink()
    path.write_text("t_s\n0.0\n")  # the user's own CSV in its place
    with pytest.raises(ValueError, match="motor_log.csv exists and is not a file this command wrote"):
        Outputs().file(path)


def test_train_resume_of_a_folder_without_a_run_is_a_named_error(tmp_path, capsys):
    """Before: ``--resume`` with a mistyped ``--out`` started a new run there without a word."""
    assert main(["train", "--algo", "dqn", "--out", str(tmp_path / "typo"), "--resume", *TINY]) == 2
    assert "holds no run to resume" in capsys.readouterr().err
    assert not (tmp_path / "typo").exists()


def test_a_dataset_the_command_did_not_write_is_the_users(tmp_path, capsys):
    """A dataset (a model, an identification file) is the command's only when its folder's manifest records
    it: one the user placed there, even a softpend dataset written elsewhere, is never replaced."""
    elsewhere, here = tmp_path / "a" / "data.npz", tmp_path / "b" / "data.npz"
    argv = ["babble", "--n-trials", "1", "--trial-length-s", "0.1", "--no-progress"]
    assert main([*argv[:1], str(elsewhere), *argv[1:]]) == 0
    here.parent.mkdir()
    here.write_bytes(elsewhere.read_bytes())  # the user's copy of a dataset
    capsys.readouterr()
    assert main([*argv[:1], str(here), *argv[1:], "--seed", "1"]) == 2
    assert "data.npz exists and is not a file this command wrote" in capsys.readouterr().err
    assert here.read_bytes() == elsewhere.read_bytes()

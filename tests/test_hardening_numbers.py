"""Numbers that would reach a loop or a child unbounded are refused up front, by the option's name.

Each case runs the command in-process under an alarm (a command that does not return fails the test instead
of hanging it) and asserts one line ``softpend ...: error: --OPTION must lie in [...]`` -- the check happens in
the parent, before any controller is built, any file is written or any twin starts.
"""

from __future__ import annotations

import contextlib
import io

import pytest
from support import alarm, refused

from softpend.checks import in_range
from softpend.cli import main


def test_in_range():
    assert in_range("--x", 2, 1, 3) == 2.0
    for value in (0.5, 3.5, float("nan"), float("inf"), "2", True, None, 10**400):
        with pytest.raises(ValueError, match=r"--x must lie in \[1, 3\]"):
            in_range("--x", value, 1, 3)


@pytest.mark.parametrize("value", ["1e-300", "0", "-5", "nan", "inf", "1e9"])
def test_rig_design_print_modulus(tmp_path, value):
    """``--print-modulus-mpa 1e-300`` drew a beam 1e100 m thick and never returned."""
    refused(["rig", "design", "--out", str(tmp_path / "d"), "--print-modulus-mpa", value], "--print-modulus-mpa")
    assert not (tmp_path / "d").exists()  # refused before the outputs were planned


def test_rig_design_refuses_an_unprintable_beam():
    from softpend.hardware.rig_design import rig_design

    with pytest.raises(ValueError, match="printable beam"):
        rig_design(print_modulus_pa=1e-294)
    with pytest.raises(ValueError, match="printable beam"):
        rig_design(print_modulus_pa=1e30)


@pytest.mark.parametrize(
    "option, value",
    [
        ("--camera-fps", "0"),
        ("--camera-fps", "1e9"),
        ("--camera-fps", "nan"),
        ("--camera-latency-ms", "-5"),
        ("--camera-latency-ms", "1e9"),
        ("--start-noise", "1e300"),
        ("--start-noise", "-1"),
        ("--tilt", "1e300"),
        ("--max-blind-ms", "1e300"),
        ("--max-blind-ms", "0"),
        ("--latency-ms", "1e9"),
        ("--counts-per-rev", "1000000000000"),
        ("--duration", "1e9"),
        ("--duration", "0"),
        ("--n-links", "100000"),
    ],
)
def test_rig_control_twin_options(tmp_path, option, value):
    """Each twin option is checked by its name before the controller is built or the twin starts (they
    ended in the camera's traceback, a struct.error, a run that never ended, or silently ran)."""
    refused(
        [
            "rig",
            "control",
            "pid",
            "--twin",
            "--out",
            str(tmp_path / "o"),
            "--duration",
            "0.2",
            "--no-progress",
            option,
            value,
        ],
        option,
    )
    assert not (tmp_path / "o").exists()


def test_rig_control_pid_gains(tmp_path):
    refused(
        ["rig", "control", "pid", "--twin", "--out", str(tmp_path / "o"), "--pid-gains", "1", "nan", "2"], "--pid-gains"
    )


def test_twin_camera_with_a_long_latency_runs(tmp_path):
    """A latency of a whole second is in range: the run waits for the first frame (no 'no frame' traceback)."""
    err = io.StringIO()
    with alarm(), contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        rc = main(
            [
                "rig",
                "control",
                "lqr",
                "--twin",
                "--out",
                str(tmp_path / "o"),
                "--duration",
                "0.2",
                "--no-progress",
                "--camera-latency-ms",
                "1000",
                "--camera-fps",
                "1",
            ]
        )
    assert rc in (0, 1) and "Traceback" not in err.getvalue(), err.getvalue()


@pytest.mark.parametrize(
    "argv, option",
    [
        (["rig", "--duration", "1e9"], "--duration"),
        (["rig", "--latency-ms", "nan", "--duration", "0.1"], "--latency-ms"),
        (["rig", "check", "--twin", "--rest-s", "1e9"], "--rest-s"),
        (["rig", "check", "--twin", "--counts-per-rev", "10000000000"], "--counts-per-rev"),
        (["rig", "babble", "--twin", "--out", "{tmp}/b", "--trial-length-s", "-1"], "--trial-length-s"),
        (["rig", "babble", "--twin", "--out", "{tmp}/b", "--duration", "1e9"], "--duration"),
        (["train", "--algo", "dqn", "--out", "{tmp}/r", "--episodes", "1000000000000"], "--episodes"),
        (["track", "--camera", "0", "--out", "{tmp}/t.csv", "--duration", "1e9"], "--duration"),
        (["track", "--camera", "0", "--out", "{tmp}/t.csv", "--camera-latency-ms", "1e9"], "--camera-latency-ms"),
        (["track", "{tmp}/v.avi", "--out", "{tmp}/t.csv", "--fps", "1e9"], "--fps"),
        (["track", "{tmp}/v.avi", "--out", "{tmp}/t.csv", "--min-area", "nan"], "--min-area"),
        (
            ["fit-model", "{tmp}/d.npz", "{tmp}/m", "--max-epochs", "1000000000", "--patience", "1000000000"],
            "--max-epochs",
        ),
        (["fit-model", "{tmp}/d.npz", "{tmp}/m", "--patience", "1000000000"], "--patience"),
        (["fit-model", "{tmp}/d.npz", "{tmp}/m", "--learning-rate", "3.4e37"], "--learning-rate"),
        (["identify", "{tmp}/d.npz", "--max-iterations", "1000000000"], "--max-iterations"),
        (["identify", "{tmp}/d.npz", "--window-s", "inf"], "--window-s"),
    ],
)
def test_other_commands_refuse_unbounded_numbers(tmp_path, argv, option):
    """Numbers that ran for ever (rig --duration 1e9, a twin babble with a negative trial length, 1e12
    training episodes, rig check --rest-s 1e9) or died in a traceback are refused by name up front."""
    refused([a.replace("{tmp}", str(tmp_path)) for a in argv], option)
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("text", ["0-999999999", "0-5,6-99999", "0-10000"])
def test_sweep_refuses_too_many_seeds_by_size(tmp_path, text):
    """``--seeds 0-999999999`` built the list first and died in a MemoryError traceback; now the size of each
    range is refused before a seed is listed."""
    import argparse

    from softpend.commands.sweep import MAX_SEEDS, seed_list

    with pytest.raises(argparse.ArgumentTypeError, match=f"more than the {MAX_SEEDS}"):
        seed_list(text)
    refused(["sweep", "--seeds", text, "--runs-root", str(tmp_path / "runs")], "--seeds", "seeds")
    assert seed_list("0-9999") == list(range(10_000)) and seed_list("0-2,7,1") == [0, 1, 2, 7]


@pytest.mark.parametrize(
    "option, value",
    [("--episodes-dqn", "1000000000000"), ("--workers", "0"), ("--pilco-trials", "-1"), ("--episodes-mbpo", "0")],
)
def test_sweep_numbers(tmp_path, option, value):
    refused(["sweep", "--seeds", "0", "--runs-root", str(tmp_path / "runs"), option, value], option)
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize(
    "option, value",
    [
        ("--tip-noise-std-m", "1e300"),
        ("--phi-noise-std-rad", "1e9"),
        ("--feedback-kp", "1e300"),
        ("--torque-std-fraction", "1e300"),
        ("--torque-bandwidth-hz", "1e300"),
    ],
)
def test_babble_refuses_a_dataset_of_noise(tmp_path, option, value):
    """``babble --tip-noise-std-m 1e300`` wrote a 'dataset' of tip positions of 1e300 m and exited 0."""
    refused(
        [
            "babble",
            str(tmp_path / "d.npz"),
            "--n-trials",
            "1",
            "--trial-length-s",
            "0.05",
            "--no-progress",
            option,
            value,
        ],
        option,
    )
    assert not (tmp_path / "d.npz").exists()


def test_learning_rates_beyond_a_float32_step_are_refused(tmp_path):
    """Adam's step ``lr / (1 - beta1)`` must stay a float32: ``fit-model --learning-rate 3.4e37`` ended in torch's
    overflow traceback.  Up to 1e30 a huge step is still taken, and diverges into the NonFiniteError of the
    training loops (tests/test_hardening_files.py)."""
    from softpend.rl.config import DQNLearner
    from softpend.sysid import TrainConfig

    refused(
        [
            "train",
            "--algo",
            "dqn",
            "--out",
            str(tmp_path / "r"),
            "--episodes",
            "1",
            "--no-progress",
            "--set",
            "learner.learning_rate=3.4e37",
        ],
        "learning_rate must lie in",
    )
    for make in (DQNLearner, TrainConfig):
        with pytest.raises(ValueError, match="learning_rate must lie in"):
            make(learning_rate=3.4e37)
        assert make(learning_rate=1e30).learning_rate == 1e30

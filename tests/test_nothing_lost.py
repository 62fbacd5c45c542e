"""Issue 68: no command replaces a file or a run it did not write, no session outlives its duration, and the
inputs that used to give a silent wrong result are named errors."""

from __future__ import annotations

import os
import subprocess
import sys
import time

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
    process = subprocess.Popen([sys.executable, "-c", "from softpend.cli import main; main()", "rig", "--duration", "25"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
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
            rc = process.wait(timeout=240)  # a hang, not a timing: 25 s of duration with ample room
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

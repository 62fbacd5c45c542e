"""Crash-safe logging: a SIGKILLed writer leaves every appended sample readable."""

from __future__ import annotations

import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from softpend.io.samplelog import SampleLog, read_sample_log

_WRITER = """
import sys, time
from softpend.io.samplelog import SampleLog
log = SampleLog(sys.argv[1], ["i", "t_s", "value"], metadata={"run": "kill-test"}, fsync_every_s=None)
i = 0
while True:
    log.append([i, time.monotonic(), 0.5 * i])
    print(i, flush=True)   # reported only after append() returned
    i += 1
    if i % 50 == 0:
        time.sleep(0.001)
"""


def test_sigkill_mid_run_loses_no_appended_sample(tmp_path):
    path = tmp_path / "samples.csv"
    writer = subprocess.Popen([sys.executable, "-c", _WRITER, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        last = -1
        for line in writer.stdout:
            last = int(line)
            if last >= 300:
                break
        os.kill(writer.pid, signal.SIGKILL)
        writer.wait(5)
    finally:
        if writer.poll() is None:
            writer.kill()
        writer.stdout.close()
    assert writer.returncode == -signal.SIGKILL
    log = read_sample_log(path)
    assert log.metadata == {"run": "kill-test"} and log.columns == ["i", "t_s", "value"]
    assert len(log) >= last + 1  # every sample reported as written is there ...
    np.testing.assert_array_equal(log["i"], np.arange(len(log)))  # ... in order, none missing
    np.testing.assert_array_equal(log["value"], 0.5 * np.arange(len(log)))
    assert log.torn_lines == 0


def test_torn_last_line_is_reported_not_parsed(tmp_path):
    path = tmp_path / "log.csv"
    with SampleLog(path, ["a_m", "b_s"]) as log:
        log.append([1.0, 2.0])
        log.append([3.0, float("nan")])
    with open(path, "a") as f:
        f.write("4.0,")  # a power cut in the middle of a line
    data = read_sample_log(path)
    assert len(data) == 2 and data.torn_lines == 1
    assert data["a_m"].tolist() == [1.0, 3.0] and np.isnan(data["b_s"][1])


def test_append_reopens_and_validates(tmp_path):
    path = tmp_path / "log.csv"
    with SampleLog(path, ["x"], fsync_every_s=0) as log:
        log.append([1])
    with SampleLog(path, ["x"]) as log:  # appending to an existing log keeps its samples
        log.append([2])
    assert read_sample_log(path)["x"].tolist() == [1.0, 2.0]
    with pytest.raises(ValueError, match="columns"):
        SampleLog(path, ["y"])
    with pytest.raises(ValueError, match="row has 2 values"):
        with SampleLog(tmp_path / "other.csv", ["x"]) as log:
            log.append([1, 2])
    with pytest.raises(ValueError, match="not a softpend sample log"):
        (tmp_path / "junk.csv").write_text("a,b\n1,2\n")
        read_sample_log(tmp_path / "junk.csv")

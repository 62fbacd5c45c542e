"""Real-time helpers of the rig loop: the scheduling request and the processors kept awake."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import psutil
import pytest

from softpend.hardware.realtime import cpus_kept_awake, realtime_priority


def _spinners() -> list[psutil.Process]:
    return [child for child in psutil.Process().children() if "SCHED_IDLE" in " ".join(child.cmdline())]


def _wait_gone(pids: list[int], timeout_s: float = 5.0) -> list[int]:
    deadline = time.monotonic() + timeout_s
    alive = list(pids)
    while alive and time.monotonic() < deadline:
        alive = [pid for pid in alive if psutil.pid_exists(pid) and psutil.Process(pid).status() != psutil.STATUS_ZOMBIE]
        time.sleep(0.05)
    return alive


def test_priority_outside_the_range_is_refused_and_none_asks_nothing():
    with pytest.raises(ValueError, match="priority"):
        with realtime_priority(0):
            pass
    with realtime_priority(None) as granted:
        assert granted is False


def test_one_idle_class_spinner_per_processor_for_the_block_only():
    assert not _spinners()
    with cpus_kept_awake(enabled=False) as count:
        assert count == 0 and not _spinners()
    with cpus_kept_awake() as count:
        spinners = _spinners()
        assert count == len(spinners) == len(os.sched_getaffinity(0))
        time.sleep(0.3)  # let them lower their own scheduling class
        for spinner in spinners:
            policy = os.sched_getscheduler(spinner.pid)
            assert policy == os.SCHED_IDLE or spinner.nice() == 19, (spinner.pid, policy)
        assert {tuple(s.cpu_affinity()) for s in spinners} == {(cpu,) for cpu in os.sched_getaffinity(0)}
    assert not _wait_gone([s.pid for s in spinners]), "spinners outlived the block"


@pytest.mark.realtime  # a share of a processor: measured with nothing else running
def test_spinners_give_their_processor_to_work_at_the_lowest_nice_level():
    # a CPU-bound program at nice 19, pinned to one processor beside that processor's spinner, gets all of it
    # (spinners that never yield leave it about 84 %: the idle class still gets its share of the processor)
    program = ("import os, time\n"
               "os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})\n"
               "os.setpriority(os.PRIO_PROCESS, 0, 19)\n"
               "start = time.perf_counter()\n"
               "while time.perf_counter() - start < 1.5:\n"
               "    pass\n"
               "print(time.process_time() / (time.perf_counter() - start))\n")
    with cpus_kept_awake() as count:
        assert count >= 1
        time.sleep(0.3)  # let them lower their own scheduling class
        share = float(subprocess.run([sys.executable, "-c", program], capture_output=True, text=True,
                                     check=True).stdout)
    assert share > 0.95, share


def test_spinners_end_by_themselves_when_their_process_dies():
    program = ("import os, sys, time\n"
               "from softpend.hardware.realtime import cpus_kept_awake\n"
               "with cpus_kept_awake() as n:\n"
               "    print(n, flush=True)\n"
               "    time.sleep(60)\n")
    parent = subprocess.Popen([sys.executable, "-c", program], stdout=subprocess.PIPE, text=True)
    try:
        assert int(parent.stdout.readline()) >= 1
        pids = [child.pid for child in psutil.Process(parent.pid).children()]
        assert pids
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        # SCHED_IDLE spinners notice their parent's death only when they get a processor, which a machine busy
        # with other work can withhold for seconds
        assert not _wait_gone(pids, timeout_s=30.0), "spinners outlived their killed process"
    finally:
        if parent.poll() is None:
            parent.kill()


@pytest.mark.realtime  # times the block's exit: run with the real-time tests, not beside other workers' load
def test_the_block_ends_at_once_when_every_processor_is_busy():
    # lowest-class spinners get no processor on a busy machine; the block must not wait for them to notice
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in os.sched_getaffinity(0)]
    try:
        time.sleep(0.2)
        with cpus_kept_awake() as count:
            spinners = _spinners()
            time.sleep(0.5)
            entered_exit = time.monotonic()
        exit_s = time.monotonic() - entered_exit
        assert count >= 1 and exit_s < 1.0, exit_s
        assert not _wait_gone([s.pid for s in spinners], timeout_s=0.5)
    finally:
        for process in busy:
            process.kill()
            process.wait()

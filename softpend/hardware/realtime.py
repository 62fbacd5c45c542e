"""Real-time scheduling for the threads that pace a rig: the host's control loop and the emulated device.

A rig's host software asks the operating system to run its control loop ahead of other work, as robot
controllers commonly do (a ``SCHED_FIFO`` thread on Linux): a loop that waits on the link most of the time then
answers each state within its own processing time, whatever else the computer runs.  The emulator, which
stands in for the rig's microcontroller with a processor of its own, asks for a higher priority still; the
twin's camera, which stands in for a camera with its own electronics, for one below the loop's, so that it
delivers its frames whatever else the computer runs but never holds a command back.

:func:`realtime_priority` asks for it and carries on at normal priority where the operating system refuses
(no privilege, or no such policy): the run is then as good as the machine's load allows, and the caller
learns which it got.

:func:`cpus_kept_awake` keeps the processor from halting while a run lasts.  A processor that halts when idle
takes time to wake when the next state arrives: microseconds on most computers, but on a virtual machine a
halted virtual processor waits for the host to run it again, which is milliseconds, and the loop's command
jitter is then set by the idle machine rather than by the loop.  It asks the kernel for the
shortest wake-up latency (``/dev/cpu_dma_latency`` 0, where permitted) and runs one spinning process per
processor at the lowest scheduling class (``SCHED_IDLE``), which hands its processor to any other runnable
work at every turn (``sched_yield``): the spinners take a processor only when nothing else wants it, and
give it up as soon as something does, even work at the lowest ``nice`` level.
"""

from __future__ import annotations

import contextlib
import os
import struct
import subprocess
import sys
from typing import Iterator, Optional

__all__ = ["CAMERA_PRIORITY", "DEVICE_PRIORITY", "LOOP_PRIORITY", "cpus_kept_awake", "realtime_priority"]

#: ``SCHED_FIFO`` priority of the host's control loop (Linux range 1-99; below the kernel's own threads).
LOOP_PRIORITY = 10

#: ``SCHED_FIFO`` priority of the emulated device (above the host loop it serves).
DEVICE_PRIORITY = 20

#: ``SCHED_FIFO`` priority of the twin's camera thread (rendering and tracking; below the host loop).
CAMERA_PRIORITY = 5


@contextlib.contextmanager
def realtime_priority(priority: Optional[int]) -> Iterator[bool]:
    """Run the calling thread under ``SCHED_FIFO`` at ``priority`` for the block, and restore its policy after.

    Yields whether the policy was granted (``False`` for ``priority=None``, on systems without it, and where
    the process lacks the privilege).  Only the calling thread changes: threads it starts later inherit the
    policy, so start helper threads (a camera) before entering, or outside, the block.
    """
    if priority is None or not hasattr(os, "sched_setscheduler"):
        yield False
        return
    if not isinstance(priority, int) or isinstance(priority, bool) or not 1 <= priority <= 99:
        raise ValueError(f"priority must be an int in 1..99 or None, got {priority!r}")
    try:
        policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (OSError, AttributeError):
        yield False
        return
    try:
        yield True
    finally:
        try:
            os.sched_setscheduler(0, policy, param)
        except OSError:
            pass


#: The spinner's program: lowest scheduling class, pinned to one processor, ends with its parent.  One thread
#: only, so that moving its one thread back to the normal class lets it run its exit at once.
_SPINNER = """
import os, sys
cpu, parent = int(sys.argv[1]), int(sys.argv[2])
try:
    os.sched_setaffinity(0, {cpu})
except OSError:
    pass
try:
    os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
except (OSError, AttributeError):
    os.nice(19)
while os.getppid() == parent:
    os.sched_yield()
"""


@contextlib.contextmanager
def cpus_kept_awake(enabled: bool = True) -> Iterator[int]:
    """Keep this process's processors from halting for the block (module docstring).

    Yields the number of spinner processes running (0 when ``enabled`` is False or none could start).  The
    spinners are killed when the block exits, and end by themselves when this process dies.
    """
    if not enabled:
        yield 0
        return
    latency_fd = None
    try:
        latency_fd = os.open("/dev/cpu_dma_latency", os.O_WRONLY)
        os.write(latency_fd, struct.pack("i", 0))  # held while the file stays open
    except OSError:
        if latency_fd is not None:
            os.close(latency_fd)
        latency_fd = None
    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else list(range(os.cpu_count() or 1))
    spinners: list[subprocess.Popen] = []
    try:
        for cpu in cpus:
            try:
                spinners.append(subprocess.Popen([sys.executable, "-c", _SPINNER, str(cpu), str(os.getpid())],
                                                 stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                                 stderr=subprocess.DEVNULL, close_fds=True))
            except OSError:
                break
        yield len(spinners)
    finally:
        # killed, not asked to end, and first moved back to the normal class: on a loaded machine a lowest-class
        # process may wait seconds for a processor, both to notice a request and to run its own exit
        for spinner in spinners:
            try:
                os.sched_setscheduler(spinner.pid, os.SCHED_OTHER, os.sched_param(0))
            except (OSError, AttributeError):
                pass
            spinner.kill()
        for spinner in spinners:
            spinner.wait()
        if latency_fd is not None:
            os.close(latency_fd)

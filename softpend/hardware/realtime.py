"""Real-time scheduling for the threads that pace a rig: the host's control loop and the emulated device.

A rig's host software asks the operating system to run its control loop ahead of other work, as robot
controllers commonly do (a ``SCHED_FIFO`` thread on Linux): a loop that waits on the link most of the time then
answers each state within its own processing time, whatever else the computer runs.  The emulator, which
stands in for the rig's microcontroller with a processor of its own, asks for a higher priority still.

:func:`realtime_priority` asks for it and carries on at normal priority where the operating system refuses
(no privilege, or no such policy): the run is then as good as the machine's load allows, and the caller
learns which it got.
"""

from __future__ import annotations

import contextlib
import os
from typing import Iterator, Optional

__all__ = ["DEVICE_PRIORITY", "LOOP_PRIORITY", "realtime_priority"]

#: ``SCHED_FIFO`` priority of the host's control loop (Linux range 1-99; below the kernel's own threads).
LOOP_PRIORITY = 10

#: ``SCHED_FIFO`` priority of the emulated device (above the host loop it serves).
DEVICE_PRIORITY = 20


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

"""Clocks of the rig stack: a real rig's wall clock; the twin's :class:`SimClock`, a deterministic event queue;
:class:`SimSerial`, the host's end of an in-memory link on it."""

from __future__ import annotations

import heapq
import math
import time
import types
from typing import Callable, Optional

#: A real rig's clock: the computer's monotonic clock.
WALL_CLOCK = types.SimpleNamespace(now_s=time.monotonic)


class SimClock:
    """Simulated time [s] from 0: a queue of events that run when the clock reaches them."""

    def __init__(self) -> None:
        self._events: list[tuple[float, int, Callable[[], None]]] = []
        self._now, self._order = 0.0, 0  # the time, and the count of events scheduled (their order at one time)

    def now_s(self) -> float:
        return self._now

    def call_at(self, time_s: float, action: Callable[[], None]) -> None:
        """Run ``action()`` when the clock reaches ``time_s`` (now, if that is past)."""
        self._order += 1
        heapq.heappush(self._events, (max(float(time_s), self._now), self._order, action))

    def wait_for(self, ready: Callable[[], bool], deadline_s: float) -> bool:
        """Run events until ``ready()``, or else up to ``deadline_s`` (the clock left there); whether ``ready()``."""
        while not ready():
            if not self._events or self._events[0][0] > deadline_s:
                if math.isfinite(deadline_s):
                    self._now = max(self._now, deadline_s)
                return False
            time_s, _, action = heapq.heappop(self._events)
            self._now = max(self._now, time_s)
            action()
        return True

    def sleep_until(self, time_s: float) -> None:
        """Run every event up to ``time_s`` and stand there."""
        self.wait_for(lambda: False, time_s)

    def next_event_s(self) -> float:
        """Time of the next event (inf when none is scheduled) [s]."""
        return self._events[0][0] if self._events else math.inf


class SimSerial:
    """What pyserial's ``Serial`` offers :class:`~softpend.hardware.driver.MotorLink`, on a :class:`SimClock`:
    ``send(data)`` takes the bytes the host writes, :meth:`deliver` brings the device's."""

    def __init__(self, clock: SimClock, send: Callable[[bytes], None]) -> None:
        self.clock, self._send, self._rx, self.is_open = clock, send, bytearray(), True
        self.timeout: Optional[float] = 0.0

    def deliver(self, data: bytes) -> None:
        """Bytes from the device reach the host."""
        if self.is_open:
            self._rx.extend(data)

    @property
    def in_waiting(self) -> int:
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes, waiting (in simulated time) up to :attr:`timeout` for the first."""
        if not self.is_open:
            raise OSError("SimSerial is closed")
        wait = math.inf if self.timeout is None else float(self.timeout)
        self.clock.wait_for(lambda: bool(self._rx), self.clock.now_s() + wait)
        out = bytes(self._rx[:size])
        del self._rx[:size]
        return out

    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise OSError("SimSerial is closed")
        self._send(bytes(data))
        return len(data)

    def flush(self) -> None:
        pass

    def close(self) -> None:
        self.is_open = False

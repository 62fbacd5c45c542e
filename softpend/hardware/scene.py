"""The rig emulator's live pose feed: what the synthetic camera of the digital twin films.

With a scene feed (:class:`~softpend.hardware.emulator.EmulatorProcess` ``scene=True``) the emulator writes,
every tick, one fixed-size binary record to a pipe: the host time of the sample (``time.monotonic()``, the
same clock in every process of the machine), the device time, and the plant's joint positions ``q``.  It
never blocks on the pipe: when nobody reads, records are dropped.  :class:`EmulatorScene` reads the pipe
and is a :class:`softpend.vision.tip_source.Scene`: the pose of the rod at any recent host time, linear
between samples.
"""

from __future__ import annotations

import errno
import os
import struct
import threading
from typing import Optional

import numpy as np

__all__ = ["EmulatorScene", "pack_scene_record", "scene_record_size"]


def _format(n_coordinates: int) -> str:
    return f"<dd{int(n_coordinates)}d"


def scene_record_size(n_coordinates: int) -> int:
    """Bytes of one record for a plant with ``n_coordinates`` joint coordinates."""
    return struct.calcsize(_format(n_coordinates))


def pack_scene_record(host_time_s: float, device_time_s: float, q: np.ndarray) -> bytes:
    """One record: host time [s], device time [s], joint positions ``q`` [rad]."""
    return struct.pack(_format(len(q)), float(host_time_s), float(device_time_s), *map(float, q))


class EmulatorScene:
    """The emulator's pose records read from the pipe ``fd`` (non-blocking), as a camera scene.

    Parameters
    ----------
    fd : int
        Read end of the scene pipe (:attr:`EmulatorProcess.scene_fd`); this object closes it.
    task : Task
        The emulator's task (its plant draws the rod from ``q``).
    keep_s : float
        History kept [s].
    """

    def __init__(self, fd: int, task, keep_s: float = 2.0) -> None:
        from softpend.vision.tip_source import PoseHistory  # here: the emulator process imports this module

        self.fd = int(fd)
        os.set_blocking(self.fd, False)
        self._plant = task.make_plant()
        self._n = self._plant.n_coordinates
        self._size = scene_record_size(self._n)
        self._format = _format(self._n)
        self._buffer = b""
        self._lock = threading.Lock()
        self.history = PoseHistory(self._plant.link_points_m, keep_s)
        self.records = 0
        self.latest_device_time_s: Optional[float] = None
        self.ended = False

    def _drain(self) -> None:
        if self.ended:
            return
        while True:
            try:
                chunk = os.read(self.fd, 65536)
            except BlockingIOError:
                break
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EWOULDBLOCK):
                    break
                self.ended = True
                break
            if not chunk:  # the emulator closed its end
                self.ended = True
                break
            self._buffer += chunk
        whole = len(self._buffer) // self._size * self._size
        for offset in range(0, whole, self._size):
            values = struct.unpack_from(self._format, self._buffer, offset)
            self.history.add(values[0], np.array(values[2:]))
            self.latest_device_time_s = values[1]
            self.records += 1
        self._buffer = self._buffer[whole:]

    def latest_time_s(self) -> Optional[float]:
        with self._lock:
            self._drain()
            return self.history.latest_time_s()

    def pose_at(self, time_s: float) -> tuple[np.ndarray, Optional[float]]:
        with self._lock:
            return self.history.pose_at(time_s)

    def close(self) -> None:
        try:
            os.close(self.fd)
        except OSError:
            pass
        self.ended = True

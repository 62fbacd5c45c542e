"""The rig emulator: the device's protocol session in front of the simulated plant (quantised encoder, lost and
garbled STATE frames, truth log), on a :class:`SimClock` (:class:`SimRig`) or a pty (:class:`RigEmulator`)."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import re
import select
import signal
import subprocess
import sys
import tempfile
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from softpend.checks import finite, in_range, in_unit_interval, instance_of, int_at_least, optional_positive
from softpend.hardware import protocol as proto
from softpend.hardware.clock import SimClock, SimSerial
from softpend.io.samplelog import SampleLog
from softpend.task import Task


@dataclass(frozen=True)
class RigConfig:
    """Settings of the emulated rig: ``task.dt_s`` is the STATE period; ``initial_tilt_rad`` starts the straight rod
    at rest tilted from upright instead of hanging; ``hold_until_commanded`` holds it until the first TORQUE."""

    task: Task = field(default_factory=lambda: Task(start_noise_rad=0.0))
    counts_per_rev: int = 4096
    latency_s: float = 0.002
    drop_probability: float = 0.0
    garble_probability: float = 0.0
    watchdog_ms: int = 100
    seed: int = 0
    duration_s: Optional[float] = None
    initial_tilt_rad: Optional[float] = None
    hold_until_commanded: bool = False

    def __post_init__(self) -> None:
        instance_of("task", self.task, Task)
        in_range("task.dt_s", self.task.dt_s, 0.001, 0.1)
        int_at_least("counts_per_rev", self.counts_per_rev, 4)
        for name in ("latency_s", "drop_probability", "garble_probability"):
            in_unit_interval(name, getattr(self, name))
        in_range("watchdog_ms", int_at_least("watchdog_ms", self.watchdog_ms, 1), 1, 65535)  # a u16 on the wire
        optional_positive("duration_s", self.duration_s)
        if self.initial_tilt_rad is not None:
            finite("initial_tilt_rad", self.initial_tilt_rad)

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "task": self.task.to_dict()}


def truth_columns(n_coordinates: int) -> list[str]:
    return (
        ["device_time_s", "applied_torque_nm"]
        + [f"q{i}_rad" for i in range(n_coordinates)]
        + [f"q{i}_dot_rad_s" for i in range(n_coordinates)]
    )


class SimRig:
    """The device on a :class:`SimClock`: tick ``k`` at ``start + k dt``, bytes either way ``latency_s`` late;
    :attr:`poses` holds the joint positions of every tick (what the camera films)."""

    def __init__(self, config: Optional[RigConfig] = None, truth_log: Optional[str | os.PathLike] = None) -> None:
        from softpend.vision.tip_source import PoseHistory

        self.clock = SimClock()
        self.config = cfg = config if config is not None else RigConfig()
        self.plant = cfg.task.make_plant()
        self.poses = PoseHistory(self.plant.link_points_m)
        self._rng = np.random.default_rng(cfg.seed)
        q, qd = (
            self.plant.hanging_state() if cfg.initial_tilt_rad is None else cfg.task.tilt_state(cfg.initial_tilt_rad)
        )
        noise = cfg.task.start_noise_rad
        q[0] += self._rng.uniform(-noise, noise)
        qd[0] += self._rng.uniform(-noise, noise)
        self.plant.reset(q, qd)
        self.session = proto.DeviceSession(
            cfg.counts_per_rev, cfg.task.torque_limit_nm, cfg.watchdog_ms, int(round(1.0 / cfg.task.dt_s))
        )
        columns, metadata = truth_columns(self.plant.n_coordinates), {"rig": cfg.to_dict()}
        self._truth = None if truth_log is None else SampleLog(truth_log, columns, metadata, fsync_every_s=None)
        self._released, self.ticks = False, 0
        self.counts = dict.fromkeys(("states_sent", "states_dropped", "states_garbled"), 0)
        self.start_s = self.clock.now_s()
        self.host: Optional[SimSerial] = None
        self.clock.call_at(self.start_s, self._on_tick)

    def tick(self, now_us: int) -> Optional[bytes]:
        """Sample the encoder at device time ``now_us`` and step the plant; the STATE frame (None if lost)."""
        cfg = self.config
        torque = self.session.torque_nm(now_us)
        observation_before = self.plant.observe()
        q, qd = self.plant.joint_state()
        if self._truth is not None:
            self._truth.append([now_us * 1e-6, torque, *q, *qd])
        self.poses.add(self.start_s + now_us * 1e-6, q.copy())
        counts = int(math.floor((q[0] - math.pi) * cfg.counts_per_rev / (2 * math.pi) + 0.5))  # 0: hanging
        frame = self.session.state_frame(now_us, counts, observation_before.phi_dot_rad_s, torque)
        self._released = self._released or self.session.last_cmd_us is not None or not cfg.hold_until_commanded
        if self._released:
            self.plant.step(torque)
        self.ticks += 1
        if frame is None:
            return None
        if cfg.drop_probability and self._rng.random() < cfg.drop_probability:
            self.counts["states_dropped"] += 1
            return None
        if cfg.garble_probability and self._rng.random() < cfg.garble_probability:
            self.counts["states_garbled"] += 1
            position = int(self._rng.integers(0, len(frame) - 1))
            garbled = bytearray(frame)
            garbled[position] = (garbled[position] ^ (1 << int(self._rng.integers(0, 8)))) or 0x5A
            frame = bytes(garbled)
        self.counts["states_sent"] += 1
        return frame

    def close(self) -> None:
        if self._truth is not None:
            self._truth.close()
            self._truth = None

    def __enter__(self) -> "SimRig":
        return self

    def __exit__(self, *exc) -> None:
        """Run 0.1 s on (the truth log records the motor after the STOP), then close."""
        try:
            self.clock.sleep_until(self.clock.now_s() + 0.1)
        finally:
            self.close()

    def stats(self) -> dict[str, float]:
        return {"ticks": float(self.ticks), **{name: float(count) for name, count in self.counts.items()}}

    def _on_tick(self) -> None:
        dt = self.config.task.dt_s
        self._to_host(self.tick(int(round(self.ticks * dt * 1e6))))
        if self.config.duration_s is None or self.ticks * dt < self.config.duration_s:
            self.clock.call_at(self.start_s + self.ticks * dt, self._on_tick)

    def _to_host(self, data: Optional[bytes]) -> None:
        host = self.host
        if data and host is not None:
            self.clock.call_at(self.clock.now_s() + self.config.latency_s, lambda: host.deliver(data))

    def _from_host(self, data: bytes) -> None:
        def arrive() -> None:
            device_us = int(round((self.clock.now_s() - self.start_s) * 1e6))
            for reply in self.session.receive(data, device_us):
                self._to_host(reply)

        self.clock.call_at(self.clock.now_s() + self.config.latency_s, arrive)

    def connect(self) -> SimSerial:
        """A new host end of the link (the one before is cut off)."""
        if self.host is not None:
            self.host.close()
        self.host = SimSerial(self.clock, self._from_host)
        return self.host


class RigEmulator(SimRig):
    """The device on a pseudo-terminal in real time, also as the symlink ``link_path`` (replacing only a pty link)."""

    def __init__(
        self,
        config: Optional[RigConfig] = None,
        truth_log: Optional[str | os.PathLike] = None,
        link_path: Optional[str | os.PathLike] = None,
    ) -> None:
        self.link_path = Path(link_path) if link_path else None
        if self.link_path is not None:
            _check_link_path(self.link_path)
        super().__init__(config, truth_log)
        self.master_fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)
        os.set_blocking(self.master_fd, False)
        self.port = os.ttyname(self._slave_fd)
        self.host, self._tail = self, b""  # type: ignore[assignment]  # device bytes go to deliver()
        self._linked = self._running = False
        try:
            if self.link_path is not None:
                _check_link_path(self.link_path)  # again: something may have appeared meanwhile
                if self.link_path.is_symlink():
                    self.link_path.unlink()
                self.link_path.symlink_to(self.port)
                self._linked = True
        except BaseException:
            self.close()
            raise

    def _write(self, data: bytes) -> bytes:
        try:
            return data[os.write(self.master_fd, data) :]
        except (BlockingIOError, InterruptedError):
            return data
        except OSError:
            return b""  # no host has the pty open

    def deliver(self, data: bytes) -> None:
        """Write to the pty: a frame it has no room for is dropped; the tail of one taken in part goes first."""
        if self._tail:
            self._tail = self._write(self._tail)
            if self._tail:
                return
        self._tail = self._write(data)
        if self._tail == data:
            self._tail = b""

    def stop(self) -> None:
        self._running = False

    def serve(self) -> None:
        """Run until :meth:`stop` or ``duration_s`` of device time, in real time."""
        duration = self.config.duration_s
        start = time.monotonic() - self.clock.now_s()
        self._running = True
        while self._running and (duration is None or self.clock.now_s() < duration):
            self.clock.sleep_until(time.monotonic() - start)
            wait = self.clock.next_event_s() - (time.monotonic() - start)
            ready, _, _ = select.select([self.master_fd], [], [], min(max(0.0, wait), 0.1))
            if ready:
                try:
                    data = os.read(self.master_fd, 4096)
                except OSError as exc:  # EIO: no host has the pty open
                    data = b""
                    if not isinstance(exc, BlockingIOError):
                        time.sleep(min(0.01, max(0.0, wait)))
                if data:
                    self.clock.sleep_until(time.monotonic() - start)
                    self._from_host(data)

    def close(self) -> None:
        for fd in (self.master_fd, self._slave_fd):
            with contextlib.suppress(OSError):
                os.close(fd)
        super().close()
        link = self.link_path
        if self._linked and link is not None and link.is_symlink() and os.readlink(link) == self.port:
            link.unlink()
        self._linked = False


def _check_link_path(path: Path) -> None:
    refusal = "refusing to replace it (remove it or choose another path)"
    if path.is_symlink():
        target = os.readlink(path)
        if not re.fullmatch(r"/dev/pts/\d+|/dev/ttys\d+", target):
            raise ValueError(
                f"link_path (--port) {path} is a symlink to {target!r}, not to a pseudo-terminal; {refusal}"
            )
    elif path.exists():
        raise ValueError(f"link_path (--port) {path} is an existing {'folder' if path.is_dir() else 'file'}; {refusal}")
    elif not path.parent.is_dir():
        raise ValueError(f"link_path (--port) {path}: folder {path.parent} does not exist")


def serve_forever(config: RigConfig, truth_log: Optional[str] = None, link_path: Optional[str] = None) -> int:
    """Create an emulator, print its pty path (one line), serve until SIGTERM or its duration."""
    emulator = RigEmulator(config, truth_log=truth_log, link_path=link_path)
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: emulator.stop())
    print(emulator.port if link_path is None else f"{emulator.port} -> {link_path}", flush=True)
    try:
        with contextlib.suppress(KeyboardInterrupt):
            emulator.serve()
    finally:
        signal.signal(signal.SIGTERM, previous)
        emulator.close()
    return 0


class EmulatorProcess:
    """A rig emulator in a child process, a context manager; :attr:`port` is its pty path."""

    def __init__(self, config: Optional[RigConfig] = None, truth_log: Optional[str | os.PathLike] = None) -> None:
        config = config if config is not None else RigConfig()
        cmd = [sys.executable, "-m", "softpend.hardware.emulator", "--config-json", json.dumps(config.to_dict())]
        cmd += [] if truth_log is None else ["--truth-log", str(truth_log)]
        self._stderr = tempfile.TemporaryFile(mode="w+")
        self.process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self._stderr, text=True)
        stdout = self.process.stdout
        assert stdout is not None
        line = stdout.readline().strip() if select.select([stdout], [], [], 20.0)[0] else ""
        if not line.startswith("/dev/"):
            self.kill()
            self._stderr.seek(0)
            raise RuntimeError(f"rig emulator did not start within 20 s: {line!r} {self._stderr.read()[-2000:]}")
        self.port = line.split()[0]

    def kill(self) -> None:
        """SIGKILL the emulator (the pulled cable)."""
        self.process.kill()
        self.process.wait()

    def terminate(self) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(5.0)
            except subprocess.TimeoutExpired:
                self.kill()

    def __enter__(self) -> "EmulatorProcess":
        return self

    def __exit__(self, *exc) -> None:
        self.terminate()
        if self.process.stdout:
            self.process.stdout.close()
        self._stderr.close()


def _main(argv: Optional[list[str]] = None) -> int:  # the child process entry point
    parser = argparse.ArgumentParser(prog="python -m softpend.hardware.emulator")
    parser.add_argument("--config-json", required=True)  # RigConfig.to_dict()
    parser.add_argument("--truth-log")
    args = parser.parse_args(argv)
    config = json.loads(args.config_json)
    return serve_forever(RigConfig(**config | {"task": Task.from_dict(config["task"])}), truth_log=args.truth_log)


if __name__ == "__main__":
    sys.exit(_main())

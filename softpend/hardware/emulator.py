"""The rig emulator: the motor controller's protocol on a pseudo-terminal, backed by the simulated plant.

:class:`RigEmulator` opens a pseudo-terminal (``os.openpty``), and serves the protocol of
:mod:`softpend.hardware.protocol` on it with the *same* device-side logic as the VEX program
(:class:`~softpend.hardware.protocol.DeviceSession`: handshake, torque clamp, watchdog).  The plant
(:func:`softpend.plant.make_plant`) advances in real time, one control step per tick; each tick the
emulator applies the session's torque, samples a quantised encoder and streams a STATE frame.  Link
imperfections are configurable (:class:`RigConfig`): encoder resolution, latency in both directions,
dropped and garbled frames.  The true joint state is recorded in a crash-safe truth log (for the
synthetic camera and for checking).

Run it as a process with ``softpend rig`` (or :func:`start_emulator_process`), which prints the pty
path, and point :class:`~softpend.hardware.driver.MotorLink` at that path like at a real rig.
"""

from __future__ import annotations

import argparse
import dataclasses
import heapq
import json
import math
import os
import re
import select
import signal
import subprocess
import sys
import time
import tty
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from softpend.checks import finite, in_unit_interval, int_at_least, optional_positive
from softpend.task import Task
from softpend.hardware import protocol as proto
from softpend.hardware.realtime import DEVICE_PRIORITY, realtime_priority
from softpend.io.samplelog import SampleLog

__all__ = ["EmulatorProcess", "RigConfig", "RigEmulator", "start_emulator_process", "truth_columns"]


@dataclass(frozen=True)
class RigConfig:
    """Settings of the emulated rig.

    Parameters
    ----------
    task : Task
        The simulated plant and rod; ``task.dt_s`` is the control (and STATE) period [s] (in [0.001, 0.1]),
        ``task.start_noise_rad`` the uniform noise on the initial hub angle and rate (the rod starts
        hanging) [rad, rad/s]; default: the default rod, no start noise.
    counts_per_rev : int
        Encoder counts per hub revolution (quantisation of the reported angle).
    latency_s : float
        One-way link latency [s], applied to received commands and to sent states.
    drop_probability : float
        Probability that a STATE frame is lost.
    garble_probability : float
        Probability that a STATE frame has one byte corrupted (fails its CRC at the host).
    watchdog_ms : int
        Device watchdog [ms].
    seed : int
        Seed for the drop/garble draws and the initial-state noise.
    duration_s : float or None
        Stop after this much device time [s] (None: run until killed or stopped).
    initial_tilt_rad : float or None
        Start with the straight rod at rest tilted by this angle from upright [rad] (plus the start noise)
        instead of hanging (None); the encoder still reads zero at the hanging position.
    hold_until_commanded : bool
        Hold the rod at its initial state until the first TORQUE command of a session (a hand holding the
        rod until the controller takes over), so that a start near upright is still near upright when
        control begins.
    """

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
        if not isinstance(self.task, Task):
            raise ValueError(f"task must be a Task, got {type(self.task).__name__}")
        if not 0.001 <= self.task.dt_s <= 0.1:
            raise ValueError(f"task.dt_s must be in [0.001, 0.1] s, got {self.task.dt_s!r}")
        int_at_least("counts_per_rev", self.counts_per_rev, 4)
        for name in ("latency_s", "drop_probability", "garble_probability"):
            in_unit_interval(name, getattr(self, name))
        if int(self.watchdog_ms) != self.watchdog_ms or not 1 <= self.watchdog_ms <= 65535:
            raise ValueError(f"watchdog_ms must be an integer in [1, 65535], got {self.watchdog_ms!r}")
        optional_positive("duration_s", self.duration_s)
        if self.initial_tilt_rad is not None:
            finite("initial_tilt_rad", self.initial_tilt_rad)

    def to_dict(self) -> dict:
        data = dataclasses.asdict(self)
        data["task"] = self.task.to_dict()
        return data

    @classmethod
    def from_dict(cls, data: dict) -> "RigConfig":
        data = dict(data)
        if "task" in data:
            data["task"] = Task.from_dict(data["task"])
        return cls(**data)


def truth_columns(n_coordinates: int) -> list[str]:
    """Columns of the emulator's truth log: device time, torque, then the full joint state."""
    return (
        ["device_time_s", "applied_torque_nm"]
        + [f"q{i}_rad" for i in range(n_coordinates)]
        + [f"q{i}_dot_rad_s" for i in range(n_coordinates)]
    )


class RigEmulator:
    """Serve the motor protocol on a pseudo-terminal, backed by the plant in real time.

    Parameters
    ----------
    config : RigConfig
        Rig settings.
    truth_log : path, optional
        Where to record the true joint state every tick (crash-safe :class:`SampleLog`).
    link_path : path, optional
        Also expose the pty at this path (a symlink), like a fixed device name.  Only a symlink to a
        pseudo-terminal (one an earlier emulator left behind) is replaced; anything else at the path
        raises ``ValueError`` and is left as it is.  :meth:`close` removes the symlink if it still points
        to this emulator's pty.
    scene_fd : int, optional
        Write end of a pipe for the live pose feed (:mod:`softpend.hardware.scene`): one record per tick
        with the host time of the sample and ``q``; written without blocking (dropped when the pipe is full).
    """

    def __init__(self, config: Optional[RigConfig] = None, truth_log: Optional[str | os.PathLike] = None,
                 link_path: Optional[str | os.PathLike] = None, scene_fd: Optional[int] = None) -> None:
        self.config = config if config is not None else RigConfig()
        cfg = self.config
        self.link_path = Path(link_path) if link_path else None
        if self.link_path is not None:
            _check_link_path(self.link_path)
        self.plant = cfg.task.make_plant()
        self._rng = np.random.default_rng(cfg.seed)
        q, qd = self.plant.hanging_state() if cfg.initial_tilt_rad is None else cfg.task.tilt_state(cfg.initial_tilt_rad)
        noise = cfg.task.start_noise_rad
        q[0] += self._rng.uniform(-noise, noise)
        qd[0] += self._rng.uniform(-noise, noise)
        self.plant.reset(q, qd)
        self._phi0_rad = math.pi  # the encoder reads zero with the rod hanging, as on the rig
        self.session = proto.DeviceSession(
            cfg.counts_per_rev, cfg.task.torque_limit_nm, cfg.watchdog_ms, int(round(1.0 / cfg.task.dt_s))
        )
        self.master_fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)
        self.port = os.ttyname(self._slave_fd)
        self._truth = None
        self._linked = False
        try:
            if self.link_path is not None:
                _check_link_path(self.link_path)  # again: something may have appeared meanwhile
                if self.link_path.is_symlink():
                    self.link_path.unlink()  # a pty symlink an earlier emulator left behind
                self.link_path.symlink_to(self.port)
                self._linked = True
            if truth_log is not None:
                self._truth = SampleLog(truth_log, truth_columns(self.plant.n_coordinates),
                                        metadata={"rig": cfg.to_dict()}, fsync_every_s=None)
        except BaseException:
            self.close()
            raise
        self._running = False
        self._scene_fd = scene_fd
        if scene_fd is not None:
            os.set_blocking(scene_fd, False)
        self._start_monotonic_s = time.monotonic()
        self.scene_records_dropped = 0
        self._released = False
        self.ticks = 0
        self.states_sent = 0
        self.states_dropped = 0
        self.states_garbled = 0
        self.ticks_skipped = 0
        self.tick_lateness_s: list[float] = []

    # ------------------------------------------------------------------ encoder model
    def encoder_counts(self, phi_unwrapped_rad: float) -> int:
        """Quantised encoder reading for a hub angle [rad]."""
        return int(math.floor((phi_unwrapped_rad - self._phi0_rad) * self.config.counts_per_rev / (2 * math.pi) + 0.5))

    # ------------------------------------------------------------------ main loop
    def stop(self) -> None:
        self._running = False

    def serve(self) -> None:
        """Run until :meth:`stop`, ``duration_s`` of device time, or SIGTERM; the plant runs in real time."""
        cfg = self.config
        session = self.session
        dt = cfg.task.dt_s
        latency = cfg.latency_s
        start = time.monotonic()
        self._start_monotonic_s = start
        inbound: list[tuple[float, int, bytes]] = []  # (deliver_at, order, data): latency on commands
        outbound: list[tuple[float, int, bytes]] = []
        order = 0
        next_tick = start + dt
        self._running = True
        forces_time_us = lambda now: int((now - start) * 1e6)  # noqa: E731  device clock [us]
        try:
            while self._running:
                now = time.monotonic()
                wake = next_tick
                if inbound:
                    wake = min(wake, inbound[0][0])
                if outbound:
                    wake = min(wake, outbound[0][0])
                ready, _, _ = select.select([self.master_fd], [], [], max(0.0, wake - now))
                now = time.monotonic()
                if ready:
                    try:
                        data = os.read(self.master_fd, 4096)
                    except OSError:
                        data = b""  # no host has the pty open (EIO): nothing to read
                        time.sleep(min(dt, max(0.0, next_tick - now)))
                    if data:
                        order += 1
                        heapq.heappush(inbound, (now + latency, order, data))
                while inbound and inbound[0][0] <= now:
                    _, _, data = heapq.heappop(inbound)
                    for reply in session.receive(data, forces_time_us(now)):
                        order += 1
                        heapq.heappush(outbound, (now + latency, order, reply))
                if now >= next_tick:
                    self.tick_lateness_s.append(now - next_tick)
                    # the physics does not wait: if the emulator fell behind, the plant catches up
                    # (steps with the torque held, truth logged) and one STATE reports the latest sample
                    due = int((now - next_tick) / dt) + 1
                    frame = None
                    for k in range(due):
                        sample_us = int(round((self.ticks + 1) * dt * 1e6))
                        frame = self._tick(sample_us, emit=k == due - 1)
                    self.ticks_skipped += due - 1
                    next_tick += due * dt
                    if frame is not None:
                        order += 1
                        heapq.heappush(outbound, (now + latency, order, frame))
                    if cfg.duration_s is not None and now - start >= cfg.duration_s:
                        self._running = False
                while outbound and outbound[0][0] <= now:
                    _, _, frame = heapq.heappop(outbound)
                    try:
                        os.write(self.master_fd, frame)
                    except OSError:
                        pass
        finally:
            self._running = False

    def _tick(self, now_us: int, emit: bool = True) -> Optional[bytes]:
        """Sample the encoder at device time ``now_us`` (= plant time), apply the session's torque for one
        step; return the STATE frame (or None if dropped)."""
        cfg = self.config
        torque = self.session.torque_nm(now_us)
        observation_before = self.plant.observe()
        if self._truth is not None or self._scene_fd is not None:
            q, qd = self.plant.joint_state()
            if self._truth is not None:
                self._truth.append([now_us * 1e-6, torque, *q, *qd])
            if self._scene_fd is not None:
                self._write_scene(now_us * 1e-6, q)
        counts = self.encoder_counts(self.plant.joint_state()[0][0])
        frame = self.session.state_frame(now_us, counts, observation_before.phi_dot_rad_s, torque) if emit else None
        self._released = self._released or self.session.last_cmd_us is not None or not cfg.hold_until_commanded
        if self._released:  # once released, never held again (a reconnect does not freeze a moving rod)
            self.plant.step(torque)
        self.ticks += 1
        if frame is None:
            return None
        if cfg.drop_probability and self._rng.random() < cfg.drop_probability:
            self.states_dropped += 1
            return None
        if cfg.garble_probability and self._rng.random() < cfg.garble_probability:
            self.states_garbled += 1
            position = int(self._rng.integers(0, len(frame) - 1))
            garbled = bytearray(frame)
            garbled[position] = (garbled[position] ^ (1 << int(self._rng.integers(0, 8)))) or 0x5A
            frame = bytes(garbled)
        self.states_sent += 1
        return frame

    def _write_scene(self, device_time_s: float, q: np.ndarray) -> None:
        from softpend.hardware.scene import pack_scene_record

        record = pack_scene_record(self._start_monotonic_s + device_time_s, device_time_s, q)
        try:
            os.write(self._scene_fd, record)  # < PIPE_BUF bytes: written whole or not at all
        except BlockingIOError:
            self.scene_records_dropped += 1
        except OSError:  # the reader went away
            self._scene_fd = None

    def close(self) -> None:
        for fd in (self.master_fd, self._slave_fd):
            try:
                os.close(fd)
            except OSError:
                pass
        if self._truth is not None:
            self._truth.close()
        if self._linked and self.link_path.is_symlink() and os.readlink(self.link_path) == self.port:
            self.link_path.unlink()
        self._linked = False

    def stats(self) -> dict[str, float]:
        lateness = np.asarray(self.tick_lateness_s) * 1e3
        return {
            "ticks": float(self.ticks),
            "states_sent": float(self.states_sent),
            "states_dropped": float(self.states_dropped),
            "states_garbled": float(self.states_garbled),
            "ticks_caught_up": float(self.ticks_skipped),
            "scene_records_dropped": float(self.scene_records_dropped),
            "tick_lateness_ms_p95": float(np.percentile(lateness, 95)) if lateness.size else float("nan"),
        }


def _is_pty_name(target: str) -> bool:
    """True for a pseudo-terminal device path (``/dev/pts/N`` on Linux, ``/dev/ttysN`` on macOS)."""
    return re.fullmatch(r"/dev/pts/\d+|/dev/ttys\d+", target) is not None


def _check_link_path(path: Path) -> None:
    """Refuse a ``link_path`` that holds anything but a symlink to a pseudo-terminal (never replaced)."""
    if path.is_symlink():
        target = os.readlink(path)
        if _is_pty_name(target):
            return
        raise ValueError(f"link_path (--port) {path} is a symlink to {target!r}, not to a pseudo-terminal; "
                         "refusing to replace it (remove it or choose another path)")
    if path.exists():
        kind = "folder" if path.is_dir() else "file"
        raise ValueError(f"link_path (--port) {path} is an existing {kind}; refusing to replace it "
                         "(remove it or choose another path)")
    if not path.parent.is_dir():
        raise ValueError(f"link_path (--port) {path}: folder {path.parent} does not exist")


# ---------------------------------------------------------------------- process helpers
def serve_forever(config: RigConfig, truth_log: Optional[str] = None, link_path: Optional[str] = None,
                  stats_path: Optional[str] = None, out=sys.stdout, scene_fd: Optional[int] = None) -> int:
    """Create an emulator, print its pty path (one line, flushed), serve until SIGTERM/duration."""
    emulator = RigEmulator(config, truth_log=truth_log, link_path=link_path, scene_fd=scene_fd)

    def _terminate(signum, frame):
        emulator.stop()

    previous = signal.signal(signal.SIGTERM, _terminate)
    print(emulator.port if link_path is None else f"{emulator.port} -> {link_path}", file=out, flush=True)
    try:
        emulator.serve()
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)
        if stats_path:
            Path(stats_path).write_text(json.dumps(emulator.stats()))
        emulator.close()
    return 0


class EmulatorProcess:
    """A rig emulator running in a child process (``python -m softpend.hardware.emulator``).

    Use as a context manager; :attr:`port` is the pty path to open with
    :class:`~softpend.hardware.driver.MotorLink`.  :meth:`kill` is the "pulled cable" fault.  With
    ``scene=True`` the emulator also writes its live pose feed to a pipe; :meth:`open_scene` gives the
    :class:`~softpend.hardware.scene.EmulatorScene` that reads it (what the twin's camera films).
    """

    def __init__(self, config: RigConfig, truth_log: Optional[str | os.PathLike] = None,
                 stats_path: Optional[str | os.PathLike] = None, start_timeout_s: float = 20.0,
                 scene: bool = False) -> None:
        cmd = [sys.executable, "-m", "softpend.hardware.emulator", "--config-json", json.dumps(config.to_dict())]
        if truth_log is not None:
            cmd += ["--truth-log", str(truth_log)]
        if stats_path is not None:
            cmd += ["--stats", str(stats_path)]
        self.stats_path = Path(stats_path) if stats_path else None
        self.config = config
        self.scene_fd: Optional[int] = None
        pass_fds: tuple[int, ...] = ()
        if scene:
            self.scene_fd, scene_write = os.pipe()
            cmd += ["--scene-fd", str(scene_write)]
            pass_fds = (scene_write,)
        import tempfile

        self._stderr = tempfile.TemporaryFile(mode="w+")
        try:
            self.process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self._stderr, text=True,
                                            pass_fds=pass_fds)
        finally:
            for fd in pass_fds:  # the child holds its own copy of the write end
                os.close(fd)
        ready, _, _ = select.select([self.process.stdout], [], [], start_timeout_s)
        line = self.process.stdout.readline().strip() if ready else ""
        if not line.startswith("/dev/"):
            self._close_scene_fd()
            self.process.kill()
            self.process.wait()
            self._stderr.seek(0)
            err = self._stderr.read()
            raise RuntimeError(f"rig emulator did not start within {start_timeout_s} s: {line!r} {err[-2000:]}")
        self.port = line.split()[0]

    def kill(self) -> None:
        """SIGKILL the emulator (the link dies without a goodbye)."""
        self.process.kill()
        self.process.wait()

    def terminate(self, timeout_s: float = 5.0) -> None:
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()

    def stats(self) -> dict[str, float]:
        """The emulator's counters (after :meth:`terminate`)."""
        if self.stats_path is None or not self.stats_path.exists():
            return {}
        return json.loads(self.stats_path.read_text())

    def __enter__(self) -> "EmulatorProcess":
        return self

    def open_scene(self):
        """The :class:`~softpend.hardware.scene.EmulatorScene` of the pose feed (``scene=True`` only); it
        owns the pipe from then on."""
        from softpend.hardware.scene import EmulatorScene

        if self.scene_fd is None:
            raise ValueError("scene: this emulator was started without a scene feed (or it was opened already)")
        fd, self.scene_fd = self.scene_fd, None
        return EmulatorScene(fd, self.config.task)

    def take_scene_fd(self) -> int:
        """The read end of the pose feed (``scene=True`` only), for another process to film; the caller owns
        it from then on."""
        if self.scene_fd is None:
            raise ValueError("scene: this emulator was started without a scene feed (or it was opened already)")
        fd, self.scene_fd = self.scene_fd, None
        return fd

    def _close_scene_fd(self) -> None:
        if self.scene_fd is not None:
            os.close(self.scene_fd)
            self.scene_fd = None

    def __exit__(self, *exc) -> None:
        self.terminate()
        self._close_scene_fd()
        if self.process.stdout:
            self.process.stdout.close()
        self._stderr.close()


def start_emulator_process(config: Optional[RigConfig] = None, **kwargs) -> EmulatorProcess:
    """Start :class:`EmulatorProcess` with ``config`` (default :class:`RigConfig`)."""
    return EmulatorProcess(config if config is not None else RigConfig(), **kwargs)


def _main(argv: Optional[list[str]] = None) -> int:  # the child process entry point
    parser = argparse.ArgumentParser(prog="python -m softpend.hardware.emulator")
    parser.add_argument("--config-json", default="{}")
    parser.add_argument("--truth-log")
    parser.add_argument("--link")
    parser.add_argument("--stats")
    parser.add_argument("--scene-fd", type=int)
    args = parser.parse_args(argv)
    config = RigConfig.from_dict(json.loads(args.config_json))
    # the emulator stands in for the rig's microcontroller, which has a processor of its own: it runs ahead of
    # the host's work where the operating system allows
    with realtime_priority(DEVICE_PRIORITY):
        return serve_forever(config, truth_log=args.truth_log, link_path=args.link, stats_path=args.stats,
                             scene_fd=args.scene_fd)


if __name__ == "__main__":
    sys.exit(_main())

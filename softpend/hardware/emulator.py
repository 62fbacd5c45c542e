"""The rig emulator: the motor controller's device side, backed by the simulated plant.

:class:`RigDevice` is the device: the *same* protocol logic as the VEX program
(:class:`~softpend.hardware.protocol.DeviceSession`: handshake, torque clamp, watchdog) in front of the plant
(:meth:`softpend.task.Task.make_plant`).  Each tick (one control period) it applies the session's torque,
samples a quantised encoder and makes a STATE frame, which may be lost or garbled
(:class:`RigConfig`); the true joint state goes to a crash-safe truth log (for checking and scoring).
Two things drive it:

* :class:`SimRig`, the digital twin: ticks and link latency on a :class:`~softpend.hardware.clock.SimClock`,
  the host talking to it through an in-memory byte channel (:meth:`SimRig.connect`), in simulated time;
* :class:`RigEmulator`, the same device on a pseudo-terminal (``os.openpty``), its events run when the wall clock
  reaches them, in a process of its own (``softpend rig``, :func:`start_emulator_process`): point
  :class:`~softpend.hardware.driver.MotorLink` at its path like at a real rig.
"""

from __future__ import annotations

import argparse
import dataclasses
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
from softpend.hardware import protocol as proto
from softpend.hardware.clock import SimClock, SimSerial
from softpend.io.samplelog import SampleLog
from softpend.task import Task

__all__ = [
    "EmulatorProcess",
    "RigConfig",
    "RigDevice",
    "RigEmulator",
    "SimRig",
    "start_emulator_process",
    "truth_columns",
]


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


class RigDevice:
    """The rig's device side: protocol session, plant, encoder, lost and garbled frames (module docstring).

    Parameters
    ----------
    config : RigConfig
        Rig settings.
    truth_log : path, optional
        Where to record the true joint state every tick (crash-safe :class:`SampleLog`).
    """

    def __init__(self, config: Optional[RigConfig] = None, truth_log: Optional[str | os.PathLike] = None) -> None:
        self.config = cfg = config if config is not None else RigConfig()
        self.plant = cfg.task.make_plant()
        self._rng = np.random.default_rng(cfg.seed)
        q, qd = (
            self.plant.hanging_state() if cfg.initial_tilt_rad is None else cfg.task.tilt_state(cfg.initial_tilt_rad)
        )
        noise = cfg.task.start_noise_rad
        q[0] += self._rng.uniform(-noise, noise)
        qd[0] += self._rng.uniform(-noise, noise)
        self.plant.reset(q, qd)
        self._phi0_rad = math.pi  # the encoder reads zero with the rod hanging, as on the rig
        self.session = proto.DeviceSession(
            cfg.counts_per_rev, cfg.task.torque_limit_nm, cfg.watchdog_ms, int(round(1.0 / cfg.task.dt_s))
        )
        self._truth = None
        if truth_log is not None:
            self._truth = SampleLog(
                truth_log, truth_columns(self.plant.n_coordinates), metadata={"rig": cfg.to_dict()}, fsync_every_s=None
            )
        self._released = False
        self.ticks = self.states_sent = self.states_dropped = self.states_garbled = 0

    def encoder_counts(self, phi_unwrapped_rad: float) -> int:
        """Quantised encoder reading for a hub angle [rad]."""
        return int(math.floor((phi_unwrapped_rad - self._phi0_rad) * self.config.counts_per_rev / (2 * math.pi) + 0.5))

    def tick(self, now_us: int, emit: bool = True) -> Optional[bytes]:
        """Sample the encoder at device time ``now_us`` (= plant time), apply the session's torque for one
        step; return the STATE frame (None if not emitted or lost)."""
        cfg = self.config
        torque = self.session.torque_nm(now_us)
        observation_before = self.plant.observe()
        q, qd = self.plant.joint_state()
        if self._truth is not None:
            self._truth.append([now_us * 1e-6, torque, *q, *qd])
        self._sampled(now_us * 1e-6, q)
        counts = self.encoder_counts(q[0])
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

    def _sampled(self, device_time_s: float, q: np.ndarray) -> None:
        """Hook: the joint positions at a tick's sample (the twin's camera films them)."""

    def close(self) -> None:
        if self._truth is not None:
            self._truth.close()
            self._truth = None

    def stats(self) -> dict[str, float]:
        return {
            "ticks": float(self.ticks),
            "states_sent": float(self.states_sent),
            "states_dropped": float(self.states_dropped),
            "states_garbled": float(self.states_garbled),
        }


class SimRig(RigDevice):
    """The digital twin's device on a :class:`~softpend.hardware.clock.SimClock` (module docstring).

    Tick ``k`` runs at ``start + k dt`` (device time ``k dt``, ``start`` the clock's time at construction); each
    STATE frame and each reply reaches the host ``latency_s`` after it was made, and each host write reaches
    the device ``latency_s`` after it was written.  :attr:`poses` holds the joint positions at every tick on the
    clock's time (what the twin's camera films).
    """

    def __init__(
        self,
        config: Optional[RigConfig] = None,
        clock: Optional[SimClock] = None,
        truth_log: Optional[str | os.PathLike] = None,
    ) -> None:
        from softpend.vision.tip_source import PoseHistory

        self.clock = clock if clock is not None else SimClock()
        self.poses = PoseHistory(self.plant_points, keep_s=2.0)
        super().__init__(config, truth_log)
        self.start_s = self.clock.now_s()
        self.host: Optional[SimSerial] = None
        self.clock.call_at(self.start_s, self._on_tick)

    def plant_points(self, q: np.ndarray) -> np.ndarray:
        return self.plant.link_points_m(q)

    def _sampled(self, device_time_s: float, q: np.ndarray) -> None:
        self.poses.add(self.start_s + device_time_s, q.copy())

    def _device_us(self) -> int:
        return int(round((self.clock.now_s() - self.start_s) * 1e6))

    def _on_tick(self) -> None:
        dt = self.config.task.dt_s
        frame = self.tick(int(round(self.ticks * dt * 1e6)))
        self._to_host(frame)
        if self.config.duration_s is None or self.ticks * dt < self.config.duration_s:
            self.clock.call_at(self.start_s + self.ticks * dt, self._on_tick)

    def _to_host(self, data: Optional[bytes]) -> None:
        host = self.host
        if data and host is not None:
            self.clock.call_at(self.clock.now_s() + self.config.latency_s, lambda: host.deliver(data))

    def _from_host(self, data: bytes) -> None:
        def arrive() -> None:
            for reply in self.session.receive(data, self._device_us()):
                self._to_host(reply)

        self.clock.call_at(self.clock.now_s() + self.config.latency_s, arrive)

    def connect(self) -> SimSerial:
        """A new host end of the link (the one before is cut off, like an unplugged cable)."""
        if self.host is not None:
            self.host.close()
        self.host = SimSerial(self.clock, self._from_host)
        return self.host


class _PtyHost:
    """The host's side of the link as the pty emulator sees it: bytes written to the pty's master end.

    The master end is non-blocking: a frame the pty has no room for (no host reads it: a host that connected
    and left, or one that stopped reading) is dropped and counted in :attr:`frames_dropped`, never waited for,
    so the emulator keeps its clock and ends at its duration.  The tail of a frame the pty took only in part
    is kept and written first next time (one frame at most), so that the host never sees a torn frame
    followed by another.
    """

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.frames_dropped = 0
        self._tail = b""

    def _write(self, data: bytes) -> bytes:
        """Write what the pty takes of ``data`` without waiting; the rest."""
        try:
            return data[os.write(self.fd, data) :]
        except (BlockingIOError, InterruptedError):
            return data
        except OSError:
            return b""  # no host has the pty open: nothing to deliver to

    def deliver(self, data: bytes) -> None:
        if self._tail:
            self._tail = self._write(self._tail)
            if self._tail:
                self.frames_dropped += 1
                return
        self._tail = self._write(data)
        if self._tail == data:
            self._tail = b""
            self.frames_dropped += 1


class RigEmulator(SimRig):
    """The twin's device on a pseudo-terminal, its clock following the wall clock (module docstring).

    :meth:`serve` runs the same events as the twin (ticks, bytes arriving after the link latency) when the wall
    clock reaches them; a tick the computer could not run on time runs late, and its STATE frame goes out late.

    Parameters
    ----------
    config, truth_log :
        As :class:`RigDevice`.
    link_path : path, optional
        Also expose the pty at this path (a symlink), like a fixed device name.  Only a symlink to a
        pseudo-terminal (one an earlier emulator left behind) is replaced; anything else at the path
        raises ``ValueError`` and is left as it is.  :meth:`close` removes the symlink if it still points
        to this emulator's pty.
    """

    def __init__(
        self,
        config: Optional[RigConfig] = None,
        truth_log: Optional[str | os.PathLike] = None,
        link_path: Optional[str | os.PathLike] = None,
    ) -> None:
        self.link_path = Path(link_path) if link_path else None
        if self.link_path is not None:
            _check_link_path(self.link_path)
        super().__init__(config, SimClock(), truth_log)
        self.master_fd, self._slave_fd = os.openpty()
        tty.setraw(self._slave_fd)
        os.set_blocking(self.master_fd, False)  # every write to the host is bounded (see _PtyHost)
        self.port = os.ttyname(self._slave_fd)
        self._pty_host = _PtyHost(self.master_fd)
        self.host = self._pty_host  # type: ignore[assignment]  # the pty's master end stands in for the host
        self._linked = False
        try:
            if self.link_path is not None:
                _check_link_path(self.link_path)  # again: something may have appeared meanwhile
                if self.link_path.is_symlink():
                    self.link_path.unlink()  # a pty symlink an earlier emulator left behind
                self.link_path.symlink_to(self.port)
                self._linked = True
        except BaseException:
            self.close()
            raise
        self._running = False

    def stop(self) -> None:
        self._running = False

    def stats(self) -> dict[str, float]:
        """:meth:`RigDevice.stats` and ``frames_dropped_full``: frames (STATEs and replies) the pty had no room
        for (no host read them)."""
        return {**super().stats(), "frames_dropped_full": float(self._pty_host.frames_dropped)}

    def serve(self) -> None:
        """Run until :meth:`stop`, ``duration_s`` of device time, or SIGTERM; the plant runs in real time."""
        duration = self.config.duration_s
        start = time.monotonic() - self.clock.now_s()
        self._running = True
        try:
            while self._running and (duration is None or self.clock.now_s() < duration):
                self.clock.sleep_until(time.monotonic() - start)  # every event that is due
                wait = self.clock.next_event_s() - (time.monotonic() - start)
                ready, _, _ = select.select([self.master_fd], [], [], min(max(0.0, wait), 0.1))
                if ready:
                    try:
                        data = os.read(self.master_fd, 4096)
                    except BlockingIOError:
                        data = b""
                    except OSError:  # no host has the pty open (EIO): nothing to read
                        data = b""
                        time.sleep(min(0.01, max(0.0, wait)))
                    if data:
                        self.clock.sleep_until(time.monotonic() - start)
                        self._from_host(data)
        finally:
            self._running = False

    def close(self) -> None:
        for fd in (self.master_fd, self._slave_fd):
            try:
                os.close(fd)
            except OSError:
                pass
        super().close()
        link = self.link_path
        if self._linked and link is not None and link.is_symlink() and os.readlink(link) == self.port:
            link.unlink()
        self._linked = False


def _is_pty_name(target: str) -> bool:
    """True for a pseudo-terminal device path (``/dev/pts/N`` on Linux, ``/dev/ttysN`` on macOS)."""
    return re.fullmatch(r"/dev/pts/\d+|/dev/ttys\d+", target) is not None


def _check_link_path(path: Path) -> None:
    """Refuse a ``link_path`` that holds anything but a symlink to a pseudo-terminal (never replaced)."""
    if path.is_symlink():
        target = os.readlink(path)
        if _is_pty_name(target):
            return
        raise ValueError(
            f"link_path (--port) {path} is a symlink to {target!r}, not to a pseudo-terminal; "
            "refusing to replace it (remove it or choose another path)"
        )
    if path.exists():
        kind = "folder" if path.is_dir() else "file"
        raise ValueError(
            f"link_path (--port) {path} is an existing {kind}; refusing to replace it "
            "(remove it or choose another path)"
        )
    if not path.parent.is_dir():
        raise ValueError(f"link_path (--port) {path}: folder {path.parent} does not exist")


# ---------------------------------------------------------------------- process helpers
def serve_forever(
    config: RigConfig,
    truth_log: Optional[str] = None,
    link_path: Optional[str] = None,
    stats_path: Optional[str] = None,
    out=sys.stdout,
) -> int:
    """Create an emulator, print its pty path (one line, flushed), serve until SIGTERM/duration."""
    emulator = RigEmulator(config, truth_log=truth_log, link_path=link_path)

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
            from softpend.io.outputs import atomic_write

            with atomic_write(stats_path, "w") as handle:
                handle.write(json.dumps(emulator.stats()))
        emulator.close()
    return 0


class EmulatorProcess:
    """A rig emulator running in a child process (``python -m softpend.hardware.emulator``).

    Use as a context manager; :attr:`port` is the pty path to open with
    :class:`~softpend.hardware.driver.MotorLink`.  :meth:`kill` is the "pulled cable" fault.
    """

    def __init__(
        self,
        config: RigConfig,
        truth_log: Optional[str | os.PathLike] = None,
        stats_path: Optional[str | os.PathLike] = None,
        start_timeout_s: float = 20.0,
    ) -> None:
        import tempfile

        cmd = [sys.executable, "-m", "softpend.hardware.emulator", "--config-json", json.dumps(config.to_dict())]
        if truth_log is not None:
            cmd += ["--truth-log", str(truth_log)]
        if stats_path is not None:
            cmd += ["--stats", str(stats_path)]
        self.stats_path = Path(stats_path) if stats_path else None
        self.config = config
        self._stderr = tempfile.TemporaryFile(mode="w+")
        self.process = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=self._stderr, text=True)
        stdout = self.process.stdout
        assert stdout is not None  # stdout=PIPE
        ready, _, _ = select.select([stdout], [], [], start_timeout_s)
        line = stdout.readline().strip() if ready else ""
        if not line.startswith("/dev/"):
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

    def __exit__(self, *exc) -> None:
        self.terminate()
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
    args = parser.parse_args(argv)
    config = RigConfig.from_dict(json.loads(args.config_json))
    return serve_forever(config, truth_log=args.truth_log, link_path=args.link, stats_path=args.stats)


if __name__ == "__main__":
    sys.exit(_main())

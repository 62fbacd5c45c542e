"""Host-side driver of the motor link: version handshake, torque clamped to the smaller of the host's and the
device's limit (as the float32 on the wire), checked STATE frames, STOP on every exit path."""

from __future__ import annotations

import atexit
import contextlib
import math
import os
import select
import signal
import threading
import weakref
from dataclasses import dataclass
from typing import Optional

import numpy as np

from softpend.checks import positive
from softpend.hardware import protocol as proto
from softpend.hardware.clock import WALL_CLOCK

#: Largest values a device may announce or report (beyond them a value is garbage).
MAX_DEVICE_TORQUE_LIMIT_NM = 1000.0
MAX_HUB_SPEED_RAD_S = 1000.0
_DEVICE_LIMITS = dict(
    counts_per_rev=1 << 24, torque_limit_nm=MAX_DEVICE_TORQUE_LIMIT_NM, watchdog_s=65.535, state_rate_hz=1e4
)


class LinkError(RuntimeError): ...  # every motor-link failure


class LinkTimeout(LinkError): ...


class LinkDisconnected(LinkError): ...


class LinkChecksumError(LinkError): ...  # too many consecutive frames failed their CRC, framing or value checks


class HandshakeError(LinkError): ...


class DeviceError(LinkError): ...


@dataclass(frozen=True)
class DeviceInfo:
    """What the device announced in its HELLO_ACK (``ValueError`` naming an impossible field)."""

    protocol_version: int
    counts_per_rev: int
    torque_limit_nm: float
    watchdog_s: float
    state_rate_hz: float

    def __post_init__(self) -> None:
        for name, high in _DEVICE_LIMITS.items():
            value = getattr(self, name)
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            if not (ok and 0 < value <= high):
                raise ValueError(f"{name} must be in (0, {high}], got {value!r}")


@dataclass(frozen=True)
class MotorState:
    """One STATE message in SI units (hub angle from upright, unwrapped; ``flags``: ``protocol.FLAG_*`` bits)."""

    host_time_s: float
    device_time_s: float
    phi_rad: float
    phi_dot_rad_s: float
    applied_torque_nm: float
    last_cmd_seq: int
    flags: int
    seq: int

    @property
    def watchdog_tripped(self) -> bool:
        return bool(self.flags & proto.FLAG_WATCHDOG)


_OPEN_LINKS: "weakref.WeakSet[MotorLink]" = weakref.WeakSet()
_HANDLERS_LOCK = threading.Lock()
_PREVIOUS_HANDLERS: dict[int, object] = {}


def _stop_all_open_links(wait: bool = True) -> None:
    for link in list(_OPEN_LINKS):
        link.emergency_stop(wait=wait)


def _signal_handler(signum, frame) -> None:  # pragma: no cover - exercised in a subprocess test
    # the main thread may hold a write lock here: never wait for it (the write in progress sends STOP)
    _stop_all_open_links(wait=False)
    previous = _PREVIOUS_HANDLERS.get(signum)
    if callable(previous):
        previous(signum, frame)
    elif signum == signal.SIGINT:
        raise KeyboardInterrupt
    else:
        raise SystemExit(128 + signum)


class MotorLink:
    """A session with the motor controller on the serial port ``port`` (or the open transport ``serial``, timed
    by its ``clock``); :attr:`max_consecutive_bad_frames` bad frames in a row raise :class:`LinkChecksumError`."""

    max_consecutive_bad_frames = 3

    def __init__(
        self,
        port: str,
        torque_limit_nm: float,
        timeout_s: float = 0.25,
        install_exit_hooks: bool = True,
        serial=None,
    ) -> None:
        if not isinstance(port, str) or not port:
            raise ValueError(f"port must be a non-empty string, got {port!r}")
        self.port, self.install_exit_hooks, self._transport = port, install_exit_hooks, serial
        self.host_torque_limit_nm = positive("torque_limit_nm", torque_limit_nm)
        self.timeout_s = positive("timeout_s", timeout_s)
        self.clock = getattr(serial, "clock", None) or WALL_CLOCK
        self.device: Optional[DeviceInfo] = None
        self._serial = None
        self._decoder = proto.FrameDecoder(validate=self._check_message)
        self._pending: list[tuple[int, int, tuple]] = []
        self._seq, self.last_command_nm, self._stop_pending = 0, 0.0, False
        self._write_lock = threading.Lock()

    @property
    def is_open(self) -> bool:
        return self._serial is not None

    @property
    def torque_limit_nm(self) -> float:
        """The smaller of the host's and the device's limit [N m]."""
        device_limit = math.inf if self.device is None else self.device.torque_limit_nm
        return min(self.host_torque_limit_nm, device_limit)

    @property
    def bad_frames(self) -> int:
        return self._decoder.bad_frames

    def open(self) -> "MotorLink":
        """Open the port and perform the version handshake (:class:`LinkDisconnected`, :class:`HandshakeError`)."""
        import serial

        try:
            self._serial = self._transport or serial.Serial(self.port, 115200, timeout=0, write_timeout=self.timeout_s)
        except (serial.SerialException, OSError) as exc:
            raise LinkDisconnected(f"cannot open serial port {self.port!r}: {exc}") from exc
        _OPEN_LINKS.add(self)
        with _HANDLERS_LOCK:  # STOP at exit and on SIGTERM/SIGINT, hooked once from the main thread
            main = threading.current_thread() is threading.main_thread()
            if self.install_exit_hooks and main and not _PREVIOUS_HANDLERS:
                atexit.register(_stop_all_open_links)
                for signum in (signal.SIGTERM, signal.SIGINT):
                    _PREVIOUS_HANDLERS[signum] = signal.getsignal(signum)
                    signal.signal(signum, _signal_handler)
        self.device, nonce = None, int.from_bytes(os.urandom(4), "little")
        try:
            self._write(proto.MSG_HELLO, (proto.PROTOCOL_VERSION, nonce))
            deadline = self.clock.now_s() + self.timeout_s
            while self.device is None:
                try:
                    _, _, values = self._next_message(deadline, (proto.MSG_HELLO_ACK,))
                except LinkTimeout as exc:
                    raise HandshakeError(f"no HELLO_ACK from {self.port!r} within {self.timeout_s:.3f} s") from exc
                version, echoed, cpr, limit, watchdog_ms, rate_hz = values
                if echoed != nonce:
                    continue  # a stale answer to an earlier session
                if version != proto.PROTOCOL_VERSION:
                    raise HandshakeError(f"device speaks protocol version {version}, host {proto.PROTOCOL_VERSION}")
                try:
                    self.device = DeviceInfo(version, cpr, limit, watchdog_ms / 1000.0, float(rate_hz))
                except ValueError as exc:
                    raise HandshakeError(f"device {self.port!r} announced an impossible HELLO_ACK: {exc}") from exc
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        """Send STOP (zero torque) and close the port.  Safe to call more than once."""
        if self._serial is None:
            return
        self.emergency_stop()
        try:
            self._serial.close()
        finally:
            self._serial = None
            _OPEN_LINKS.discard(self)

    def __enter__(self) -> "MotorLink":
        return self if self.is_open else self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:  # pragma: no cover - garbage collection timing
        with contextlib.suppress(Exception):
            self.close()

    def send_torque(self, torque_nm: float) -> int:
        """Command a torque clamped to :attr:`torque_limit_nm`; its seq (``ValueError`` and a stop if not finite)."""
        try:
            torque = math.nan if isinstance(torque_nm, (str, bytes, bool)) else float(torque_nm)
        except (TypeError, ValueError):
            torque = math.nan
        if not math.isfinite(torque):
            self.emergency_stop()
            raise ValueError(f"torque_nm must be a finite number, got {torque_nm!r} (motor stopped)")
        limit = self.torque_limit_nm
        wire = np.float32(min(max(torque, -limit), limit))  # the float32 on the wire, one step in if beyond the limit
        torque = float(np.nextafter(wire, np.float32(0)) if abs(float(wire)) > limit else wire)
        seq = self._write(proto.MSG_TORQUE, (torque,))
        self.last_command_nm = torque
        return seq

    def stop(self) -> None:
        """Zero torque now (STOP message)."""
        self._write(proto.MSG_STOP, ())
        self.last_command_nm = 0.0

    def ping(self) -> float:
        """Round-trip time of a HEARTBEAT [s]."""
        start = self.clock.now_s()
        seq = self._write(proto.MSG_HEARTBEAT, ())
        deadline = start + self.timeout_s
        while True:
            _, ack_seq, _ = self._next_message(deadline, (proto.MSG_HEARTBEAT_ACK,))
            if ack_seq == seq:
                return self.clock.now_s() - start

    def read_state(self, timeout_s: Optional[float] = None) -> MotorState:
        """Wait for the next STATE frame (a link error stops the motor before it is raised)."""
        deadline = self.clock.now_s() + (self.timeout_s if timeout_s is None else float(timeout_s))
        _, seq, values = self._next_message(deadline, (proto.MSG_STATE,))
        return self._state_from(seq, values)

    def drain_states(self) -> list[MotorState]:
        """Every STATE frame already received (without waiting), oldest first."""
        self._accept(self._read_bytes(0.0))
        states = [self._state_from(s, v) for t, s, v in self._pending if t == proto.MSG_STATE]
        self._pending = [m for m in self._pending if m[0] != proto.MSG_STATE]
        return states

    def _check_message(self, msg_type: int, values: tuple) -> Optional[str]:
        """What is impossible about a decoded message's values (None: nothing)."""
        if msg_type != proto.MSG_STATE:
            return None
        _, _, velocity, applied, _, flags = values
        if not (math.isfinite(velocity) and abs(velocity) <= MAX_HUB_SPEED_RAD_S):
            return f"velocity_rad_s {velocity!r} is not finite or beyond {MAX_HUB_SPEED_RAD_S} rad/s"
        limit = self.device.torque_limit_nm if self.device is not None else MAX_DEVICE_TORQUE_LIMIT_NM
        if not (math.isfinite(applied) and abs(applied) <= limit * (1 + 1e-6)):
            return f"applied_torque_nm {applied!r} is not finite or beyond the device limit {limit!r} N m"
        if flags & ~proto.FLAG_MASK:
            return f"flags 0x{flags:02x} has undefined bits"
        return None

    def _state_from(self, seq: int, values: tuple) -> MotorState:
        device_us, counts, velocity, applied, last_cmd, flags = values  # the struct's ints and floats
        phi = math.pi + counts * (2 * math.pi / (self.device.counts_per_rev if self.device else 1))  # 0: hanging
        return MotorState(self.clock.now_s(), device_us * 1e-6, phi, velocity, applied, last_cmd, flags, seq)

    def _require_open(self):
        if self._serial is None:
            raise LinkDisconnected(f"link to {self.port!r} is not open")
        return self._serial

    def _frame(self, msg_type: int, values: tuple) -> bytes:
        self._seq = (self._seq + 1) & 0xFFFF
        return proto.encode_message(msg_type, self._seq, values)

    def _write(self, msg_type: int, values: tuple) -> int:
        import serial

        ser = self._require_open()
        try:
            with self._write_lock:
                _write_frame(ser, self._frame(msg_type, values), self.timeout_s)
        except (serial.SerialException, OSError) as exc:
            raise self._fail(LinkDisconnected(f"write to {self.port!r} failed: {exc}")) from exc
        finally:
            if self._stop_pending:  # a signal arrived during the write above
                self.emergency_stop()
        return self._seq

    def emergency_stop(self, wait: bool = True) -> None:
        """Send STOP if the port is open, swallowing any error; without ``wait`` a held write lock defers it."""
        ser = self._serial
        if ser is None:
            return
        if not self._write_lock.acquire(blocking=wait, timeout=self.timeout_s if wait else -1):
            self._stop_pending = True
            return
        try:
            self._stop_pending = False
            _write_frame(ser, self._frame(proto.MSG_STOP, ()), self.timeout_s)
            ser.flush()
        except Exception:
            pass
        finally:
            self._write_lock.release()
        self.last_command_nm = 0.0

    def _fail(self, error: LinkError) -> LinkError:
        self.emergency_stop()
        return error

    def _read_bytes(self, wait_s: float) -> bytes:
        import serial

        ser = self._require_open()
        try:
            ser.timeout = max(0.0, wait_s)
            first = ser.read(1)
            if not first:
                return b""
            waiting = ser.in_waiting
            return first + (ser.read(waiting) if waiting else b"")
        except (serial.SerialException, OSError, TypeError) as exc:
            raise self._fail(LinkDisconnected(f"serial port {self.port!r} disconnected: {exc}")) from exc

    def _accept(self, data: bytes) -> None:
        messages, errors = self._decoder.feed(data)
        for msg_type, _, values in messages:
            if msg_type == proto.MSG_ERROR:
                unknown = f"unknown error code {values[0]} (not in protocol version {proto.PROTOCOL_VERSION})"
                meaning = proto.ERROR_MEANINGS.get(values[0], unknown)
                if self.device is None:  # the answer to our HELLO
                    raise self._fail(HandshakeError(f"device {self.port!r} refused the handshake: {meaning}"))
                raise self._fail(DeviceError(f"device {self.port!r} reported an error: {meaning}"))
        self._pending.extend(messages)
        if errors and self._decoder.consecutive_bad >= self.max_consecutive_bad_frames:
            bad, last = self._decoder.consecutive_bad, self._decoder.last_error
            message = f"{bad} consecutive bad frames from {self.port!r} (last: {last}); motor stopped"
            raise self._fail(LinkChecksumError(message))

    def _next_message(self, deadline: float, wanted: tuple[int, ...]) -> tuple[int, int, tuple]:
        """The oldest wanted message, waiting until ``deadline`` for one (the port is read once more at it)."""
        last_look = False
        while True:
            for i, message in enumerate(self._pending):
                if message[0] in wanted:
                    del self._pending[i]
                    return message
            if len(self._pending) > 256:
                self._pending = self._pending[-64:]
            remaining = deadline - self.clock.now_s()
            if remaining <= 0:
                if last_look:
                    names = "/".join(proto.MESSAGE_NAMES[w] for w in wanted)
                    raise self._fail(LinkTimeout(f"no {names} from {self.port!r} within the timeout; motor stopped"))
                last_look, remaining = True, 0.0
            self._accept(self._read_bytes(remaining))


def _write_frame(ser, frame: bytes, timeout_s: float) -> None:
    """Write ``frame`` whole to ``ser``, timing out only when the port takes no byte for ``timeout_s``."""
    import serial

    try:
        fd = ser.fileno()
    except (AttributeError, OSError, ValueError):
        ser.write(frame)
        return
    view = memoryview(frame)
    while view:
        with contextlib.suppress(BlockingIOError, InterruptedError):
            view = view[os.write(fd, view) :]
        if view:
            _, writable, _ = select.select([], [fd], [], timeout_s)
            if not writable:
                raise serial.SerialTimeoutException(
                    f"write timeout: the port took no byte for {timeout_s:g} s ({len(view)} of {len(frame)} "
                    "bytes unsent)"
                )

# softpend motor controller for the VEX V5 brain (VEXcode / V5 Python, MicroPython-based).
#
# Serves the softpend motor-link protocol (documented in the embedded protocol section below) on the
# brain's USB serial port: HELLO/HELLO_ACK handshake, TORQUE commands, HEARTBEAT, STOP, and a STATE
# stream (encoder angle and velocity with device timestamps) at STATE_RATE_HZ.  The session logic, the
# torque clamp and the 100 ms watchdog are the shared DeviceSession class, the same code the rig
# emulator (softpend.hardware.emulator) runs, so host tests against the emulator exercise it.
#
# This file cannot run off the brain (the `vex` module exists only there); it is kept importable-free of
# host packages on purpose.  The protocol section is a verbatim copy of softpend/hardware/protocol.py,
# checked by tests/test_hardware_protocol.py; refresh it with
#     python -m softpend.hardware.firmware --update
#
# Hardware assumptions (edit to match the rig): V5 Smart Motor on PORT1 with the 18:1 cartridge
# (green), the rod clamped to its output shaft, rod hanging down at power-up (encoder zero = hanging).
# The V5 motor has no torque mode; the commanded torque is turned into a voltage with the DC motor
# model  V = R * tau / k_t + k_e * omega  (constants below, from the V5 motor's published curves:
# stall torque 2.1 N m at 12 V with 18:1, free speed 200 rpm).

# ---- BEGIN softpend/hardware/protocol.py (verbatim copy; do not edit here) ----
# softpend motor-link protocol, version 1: shared verbatim by the host driver, the rig emulator and the VEX V5
# program (firmware/vex_v5_motor.py embeds a copy), so it uses only what MicroPython offers (``struct``).
#
# Frame: COBS(payload || CRC-16/CCITT-FALSE(payload), big-endian) || 0x00, payload = type:u8, seq:u16, body
# (little-endian, MESSAGE_FORMATS).  Host -> device: HELLO (version, nonce), TORQUE (N m, feeds the watchdog),
# HEARTBEAT, STOP.  Device -> host: HELLO_ACK (version, nonce, counts_per_rev, torque_limit_nm, watchdog_ms,
# state_rate_hz), STATE (device_time_us, encoder_counts, velocity_rad_s, applied_torque_nm, last_cmd_seq, flags),
# HEARTBEAT_ACK (echoes the seq), ERROR (code).

import struct

PROTOCOL_VERSION = 1

MSG_HELLO = 0x01
MSG_TORQUE = 0x02
MSG_HEARTBEAT = 0x03
MSG_STOP = 0x04
MSG_HELLO_ACK = 0x81
MSG_STATE = 0x82
MSG_HEARTBEAT_ACK = 0x83
MSG_ERROR = 0x84

FLAG_WATCHDOG = 0x01
FLAG_SATURATED = 0x02
FLAG_STOPPED = 0x04
FLAG_MASK = FLAG_WATCHDOG | FLAG_SATURATED | FLAG_STOPPED

ERR_VERSION = 1
ERR_NO_SESSION = 2
ERR_BAD_MESSAGE = 3
ERROR_MEANINGS = {
    ERR_VERSION: "protocol version mismatch (ERR_VERSION): the device does not speak version %d; flash"
    " firmware/vex_v5_motor.py from this package, or use the package version that matches the device"
    % PROTOCOL_VERSION,
    ERR_NO_SESSION: "no session open (ERR_NO_SESSION): a command arrived before the HELLO handshake"
    " (did the device restart?)",
    ERR_BAD_MESSAGE: "message type not accepted by the device (ERR_BAD_MESSAGE)",
}

HEADER_FORMAT = "<BH"
HEADER_SIZE = 3
_MESSAGES = (
    (MSG_HELLO, "HELLO", "<HI"),
    (MSG_TORQUE, "TORQUE", "<f"),
    (MSG_HEARTBEAT, "HEARTBEAT", "<"),
    (MSG_STOP, "STOP", "<"),
    (MSG_HELLO_ACK, "HELLO_ACK", "<HIIfHH"),
    (MSG_STATE, "STATE", "<QiffHB"),
    (MSG_HEARTBEAT_ACK, "HEARTBEAT_ACK", "<"),
    (MSG_ERROR, "ERROR", "<B"),
)
MESSAGE_FORMATS = {t: fmt for t, _, fmt in _MESSAGES}
MESSAGE_NAMES = {t: name for t, name, _ in _MESSAGES}
MAX_FRAME_BYTES = 64


class ProtocolError(Exception): ...  # a frame that cannot be decoded


class ChecksumMismatch(ProtocolError): ...  # the CRC of a frame does not match its payload


def crc16_ccitt(data, crc=0xFFFF):
    """CRC-16/CCITT-FALSE of ``data`` (poly 0x1021, init 0xFFFF)."""
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ (0x1021 if crc & 0x8000 else 0)) & 0xFFFF
    return crc


def cobs_encode(data):
    """COBS-encode ``data`` (no 0x00 byte in the result; no delimiter added)."""
    out, block = bytearray(), bytearray()
    for byte in data:
        if byte:
            block.append(byte)
        if not byte or len(block) == 254:  # a zero, or a full block (code 255: no zero follows)
            out.append(len(block) + 1)
            out.extend(block)
            block = bytearray()
    out.append(len(block) + 1)
    out.extend(block)
    return bytes(out)


def cobs_decode(data):
    """Inverse of :func:`cobs_encode`; raises :class:`ProtocolError` on a malformed block."""
    out, i, n = bytearray(), 0, len(data)
    while i < n:
        code = data[i]
        if code == 0:
            raise ProtocolError("COBS: zero byte inside a frame")
        end = i + code
        if end > n:
            raise ProtocolError("COBS: block runs past the end of the frame")
        out.extend(data[i + 1 : end])
        i = end
        if code < 255 and i < n:
            out.append(0)
    return bytes(out)


def encode_message(msg_type, seq, values=()):
    """One complete wire frame of the body ``values`` (``MESSAGE_FORMATS[msg_type]``), delimiter included."""
    if msg_type not in MESSAGE_FORMATS:
        raise ValueError("msg_type: unknown message type %r" % (msg_type,))
    payload = struct.pack(HEADER_FORMAT, msg_type, seq & 0xFFFF) + struct.pack(MESSAGE_FORMATS[msg_type], *values)
    crc = crc16_ccitt(payload)
    return cobs_encode(payload + bytes(((crc >> 8) & 0xFF, crc & 0xFF))) + b"\x00"


def decode_frame(frame):
    """Decode one frame (without its delimiter) into ``(msg_type, seq, values)`` (:class:`ProtocolError`)."""
    raw = cobs_decode(frame)
    if len(raw) < HEADER_SIZE + 2:
        raise ProtocolError("frame too short (%d bytes)" % len(raw))
    payload, received = raw[:-2], (raw[-2] << 8) | raw[-1]
    if crc16_ccitt(payload) != received:
        raise ChecksumMismatch("CRC mismatch (got 0x%04x, computed 0x%04x)" % (received, crc16_ccitt(payload)))
    msg_type, seq = struct.unpack(HEADER_FORMAT, payload[:HEADER_SIZE])
    fmt = MESSAGE_FORMATS.get(msg_type)
    if fmt is None:
        raise ProtocolError("unknown message type 0x%02x" % msg_type)
    body = payload[HEADER_SIZE:]
    if len(body) != struct.calcsize(fmt):
        raise ProtocolError(
            "%s body has %d bytes, expected %d" % (MESSAGE_NAMES[msg_type], len(body), struct.calcsize(fmt))
        )
    return msg_type, seq, struct.unpack(fmt, body)


class FrameDecoder:
    """Incremental receiver: bytes in, decoded messages out; bad frames are counted and reported, never raised.
    ``validate(msg_type, values)`` returns None or what is wrong with the values (then a bad frame too)."""

    def __init__(self, validate=None):
        self._frame, self._overflow, self._validate = bytearray(), False, validate
        self.bad_frames = self.checksum_errors = self.value_errors = self.consecutive_bad = 0
        self.last_error = None

    def feed(self, data):
        """Add received bytes; ``(messages, errors)`` of the frames they complete."""
        messages, errors = [], []
        for byte in data:
            if byte != 0:
                if len(self._frame) < MAX_FRAME_BYTES:
                    self._frame.append(byte)
                else:
                    self._overflow = True
                continue
            frame, overflow = bytes(self._frame), self._overflow
            self._frame, self._overflow = bytearray(), False
            if not frame:
                continue
            try:
                if overflow:
                    raise ProtocolError("frame longer than %d bytes" % MAX_FRAME_BYTES)
                message = decode_frame(frame)
                problem = self._validate(message[0], message[2]) if self._validate is not None else None
                if problem is not None:
                    self.value_errors += 1
                    raise ProtocolError("%s frame refused: %s" % (MESSAGE_NAMES[message[0]], problem))
            except (ProtocolError, ValueError, struct.error) as exc:
                self.checksum_errors += int(isinstance(exc, ChecksumMismatch))
                self.consecutive_bad += 1
                self.bad_frames += 1
                self.last_error = str(exc)
                errors.append(self.last_error)
                continue
            messages.append(message)
            self.consecutive_bad = 0
        return messages, errors


class DeviceSession:
    """The device side: session, torque clamp (commands beyond ``torque_limit_nm`` are clamped and flagged) and
    watchdog (zero torque when no TORQUE arrived for ``watchdog_ms``).  The caller owns the clock [us], the motor
    and the encoder: it feeds bytes to :meth:`receive`, applies :meth:`torque_nm`, sends :meth:`state_frame`."""

    def __init__(self, counts_per_rev, torque_limit_nm, watchdog_ms=100, state_rate_hz=100):
        self.counts_per_rev, self.torque_limit_nm = int(counts_per_rev), float(torque_limit_nm)
        self.watchdog_ms, self.state_rate_hz = int(watchdog_ms), int(state_rate_hz)
        self.decoder = FrameDecoder()
        self.session_open = self.stopped = self.saturated = False
        self.command_nm, self.last_cmd_seq, self.last_cmd_us, self.tx_seq = 0.0, 0, None, 0

    def receive(self, data, now_us):
        """Process received bytes at device time ``now_us``; the reply frames to send."""
        replies = []
        messages, _errors = self.decoder.feed(data)
        for msg_type, seq, values in messages:
            if msg_type == MSG_HELLO:
                if values[0] != PROTOCOL_VERSION:
                    replies.append(encode_message(MSG_ERROR, seq, (ERR_VERSION,)))
                    continue
                self.session_open, self.command_nm, self.last_cmd_us, self.stopped = True, 0.0, None, False
                ack = (PROTOCOL_VERSION, values[1], self.counts_per_rev, self.torque_limit_nm, self.watchdog_ms)
                replies.append(encode_message(MSG_HELLO_ACK, seq, ack + (self.state_rate_hz,)))
            elif not self.session_open:
                replies.append(encode_message(MSG_ERROR, seq, (ERR_NO_SESSION,)))
            elif msg_type == MSG_TORQUE:
                torque = values[0]
                if not (torque == torque) or torque in (float("inf"), float("-inf")):
                    torque = 0.0
                limit = self.torque_limit_nm
                self.saturated = torque > limit or torque < -limit
                self.command_nm = min(max(torque, -limit), limit)
                self.last_cmd_seq, self.last_cmd_us, self.stopped = seq, now_us, False
            elif msg_type == MSG_STOP:
                self.command_nm, self.stopped = 0.0, True
            elif msg_type == MSG_HEARTBEAT:
                replies.append(encode_message(MSG_HEARTBEAT_ACK, seq, ()))
            else:
                replies.append(encode_message(MSG_ERROR, seq, (ERR_BAD_MESSAGE,)))
        return replies

    def watchdog_tripped(self, now_us):
        """Commands were received, but none for ``watchdog_ms``."""
        return self.last_cmd_us is not None and now_us - self.last_cmd_us > self.watchdog_ms * 1000

    def torque_nm(self, now_us):
        """Torque to apply now [N m]: the clamped command, or 0 after STOP or a watchdog trip."""
        if not self.session_open or self.stopped or self.watchdog_tripped(now_us):
            return 0.0
        return self.command_nm

    def flags(self, now_us):
        watchdog = FLAG_WATCHDOG if self.watchdog_tripped(now_us) else 0
        return watchdog | (FLAG_SATURATED if self.saturated else 0) | (FLAG_STOPPED if self.stopped else 0)

    def state_frame(self, now_us, encoder_counts, velocity_rad_s, applied_torque_nm):
        """A STATE frame for an encoder sample taken at ``now_us`` (None before the handshake)."""
        if not self.session_open:
            return None
        self.tx_seq = (self.tx_seq + 1) & 0xFFFF
        values = (now_us, encoder_counts, velocity_rad_s, applied_torque_nm, self.last_cmd_seq, self.flags(now_us))
        return encode_message(MSG_STATE, self.tx_seq, values)
# ---- END softpend/hardware/protocol.py ----

import sys

try:
    from vex import Brain, Motor, Ports, GearSetting, FORWARD, VOLT, DEGREES, RPM, BRAKE, COAST  # noqa: F401
except ImportError:  # pragma: no cover - only on the host, where this file is never run
    Brain = None

PORT = "PORT1"
COUNTS_PER_REV = 1800            # V5 encoder, 18:1 cartridge: 900 ticks per output rev x 2 (degrees mode: 0.2 deg)
TORQUE_LIMIT_NM = 0.06           # the project's default rod torque limit
WATCHDOG_MS = 100
STATE_RATE_HZ = 100
SUPPLY_V = 12.0
STALL_TORQUE_NM = 2.1            # at 12 V, 18:1 output
FREE_SPEED_RAD_S = 200.0 * 2 * 3.141592653589793 / 60.0
K_T = STALL_TORQUE_NM / SUPPLY_V             # N m per volt at stall (lumped R / k_t)
K_E = SUPPLY_V / FREE_SPEED_RAD_S            # back-EMF volts per rad/s


def torque_to_volts(torque_nm, omega_rad_s):
    """Voltage that produces ``torque_nm`` at speed ``omega_rad_s`` (DC motor model), clamped to supply."""
    volts = torque_nm / K_T + K_E * omega_rad_s
    return max(-SUPPLY_V, min(SUPPLY_V, volts))


def main():
    brain = Brain()
    motor = Motor(getattr(Ports, PORT), GearSetting.RATIO_18_1, False)
    motor.reset_position()
    motor.set_stopping(COAST)
    session = DeviceSession(COUNTS_PER_REV, TORQUE_LIMIT_NM, WATCHDOG_MS, STATE_RATE_HZ)  # noqa: F821
    port_in = sys.stdin.buffer if hasattr(sys.stdin, "buffer") else sys.stdin
    port_out = sys.stdout.buffer if hasattr(sys.stdout, "buffer") else sys.stdout
    period_us = 1000000 // STATE_RATE_HZ
    next_us = brain.timer.system_high_res() + period_us
    while True:
        now_us = brain.timer.system_high_res()
        # non-blocking read of whatever the host sent (the V5 USB serial is line-buffer free in raw mode)
        data = port_in.read(64) if _bytes_waiting(port_in) else b""
        for reply in session.receive(data or b"", now_us):
            port_out.write(reply)
        omega = motor.velocity(RPM) * 2 * 3.141592653589793 / 60.0
        torque = session.torque_nm(now_us)      # 0 after STOP or when the watchdog trips
        if torque == 0.0:
            motor.stop()
        else:
            motor.spin(FORWARD, torque_to_volts(torque, omega), VOLT)
        if now_us >= next_us:
            counts = int(motor.position(DEGREES) * COUNTS_PER_REV / 360.0)
            frame = session.state_frame(now_us, counts, omega, torque)
            if frame is not None:
                port_out.write(frame)
            next_us += period_us


def _bytes_waiting(stream):
    try:
        import select
        return bool(select.select([stream], [], [], 0)[0])
    except Exception:
        return True


if __name__ == "__main__" and Brain is not None:
    main()

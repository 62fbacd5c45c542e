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

"""The motor-link protocol: framing, checksums, messages, the device session, and the firmware copy."""

from __future__ import annotations

import ast
import math
import struct

import numpy as np
import pytest

from softpend.hardware import protocol as proto
from softpend.hardware.firmware import FIRMWARE_PATH, PROTOCOL_PATH, embedded_protocol


def test_crc16_ccitt_false_check_value():
    # the standard check value of CRC-16/CCITT-FALSE
    assert proto.crc16_ccitt(b"123456789") == 0x29B1
    assert proto.crc16_ccitt(b"") == 0xFFFF


@pytest.mark.parametrize("length", [0, 1, 5, 253, 254, 255, 600])
def test_cobs_round_trip_removes_every_zero(length):
    rng = np.random.default_rng(length)
    data = bytes(rng.integers(0, 4, size=length).astype(np.uint8))  # many zeros
    encoded = proto.cobs_encode(data)
    assert 0 not in encoded
    assert proto.cobs_decode(encoded) == data


def test_every_message_round_trips():
    examples = {
        proto.MSG_HELLO: (1, 0xDEADBEEF),
        proto.MSG_TORQUE: (-0.03125,),
        proto.MSG_HEARTBEAT: (),
        proto.MSG_STOP: (),
        proto.MSG_HELLO_ACK: (1, 7, 4096, 0.0625, 100, 100),
        proto.MSG_STATE: (2**40 + 5, -12345, 1.5, -0.0625, 65535, proto.FLAG_WATCHDOG | proto.FLAG_STOPPED),
        proto.MSG_HEARTBEAT_ACK: (),
        proto.MSG_ERROR: (proto.ERR_VERSION,),
    }
    assert set(examples) == set(proto.MESSAGE_FORMATS)
    for seq, (msg_type, values) in enumerate(examples.items()):
        frame = proto.encode_message(msg_type, seq + 65530, values)
        assert frame.endswith(b"\x00") and frame.count(0) == 1
        assert proto.decode_frame(frame[:-1]) == (msg_type, (seq + 65530) & 0xFFFF, values)


def test_decoder_handles_split_frames_garbage_and_bad_crc():
    good = proto.encode_message(proto.MSG_TORQUE, 9, (0.5,))
    raw = bytearray(proto.cobs_decode(good[:-1]))
    raw[4] ^= 0x10  # flip one payload bit but keep the framing valid: the CRC must catch it
    corrupt = proto.cobs_encode(bytes(raw)) + b"\x00"
    decoder = proto.FrameDecoder()
    stream = b"\x13\x37\x00" + good[:4]
    messages, errors = decoder.feed(stream)
    assert messages == [] and len(errors) == 1  # leading garbage is one bad frame, then resync
    messages, errors = decoder.feed(good[4:] + bytes(corrupt) + good)
    assert [m[:2] for m in messages] == [(proto.MSG_TORQUE, 9), (proto.MSG_TORQUE, 9)]
    assert decoder.checksum_errors == 1 and decoder.bad_frames == 2
    assert decoder.consecutive_bad == 0
    decoder.feed(bytes(corrupt) * 3)
    assert decoder.consecutive_bad == 3
    with pytest.raises(proto.ChecksumMismatch):
        proto.decode_frame(bytes(corrupt)[:-1])


def test_encode_rejects_unknown_type():
    with pytest.raises(ValueError, match="msg_type"):
        proto.encode_message(0x7F, 1, ())
    with pytest.raises(struct.error):
        proto.encode_message(proto.MSG_TORQUE, 1, ())


def _hello(session, version=proto.PROTOCOL_VERSION, now_us=0):
    return session.receive(proto.encode_message(proto.MSG_HELLO, 1, (version, 42)), now_us)


def test_device_session_handshake_clamp_and_watchdog():
    session = proto.DeviceSession(counts_per_rev=1000, torque_limit_nm=0.06, watchdog_ms=100)
    # commands before the handshake are refused
    replies = session.receive(proto.encode_message(proto.MSG_TORQUE, 1, (0.01,)), 0)
    assert proto.decode_frame(replies[0][:-1])[0] == proto.MSG_ERROR
    assert session.torque_nm(0) == 0.0
    (ack,) = _hello(session)
    msg_type, _, values = proto.decode_frame(ack[:-1])
    assert msg_type == proto.MSG_HELLO_ACK and values[1] == 42 and values[2] == 1000 and values[4] == 100
    session.receive(proto.encode_message(proto.MSG_TORQUE, 5, (1.0,)), 1_000)
    assert session.torque_nm(50_000) == pytest.approx(0.06)  # clamped on the device too
    assert session.flags(50_000) & proto.FLAG_SATURATED
    assert session.torque_nm(100_999) == pytest.approx(0.06)
    assert session.torque_nm(101_001) == 0.0  # 100 ms without a TORQUE: watchdog
    assert session.flags(101_001) & proto.FLAG_WATCHDOG
    session.receive(proto.encode_message(proto.MSG_HEARTBEAT, 6, ()), 150_000)
    assert session.torque_nm(150_000) == 0.0  # heartbeats do not feed the watchdog
    session.receive(proto.encode_message(proto.MSG_TORQUE, 7, (-0.02,)), 200_000)
    assert session.torque_nm(200_000) == pytest.approx(-0.02)
    session.receive(proto.encode_message(proto.MSG_STOP, 8, ()), 210_000)
    assert session.torque_nm(210_000) == 0.0 and session.flags(210_000) & proto.FLAG_STOPPED
    session.receive(proto.encode_message(proto.MSG_TORQUE, 9, (math.nan,)), 220_000)
    assert session.torque_nm(220_000) == 0.0  # a NaN command never reaches the motor
    frame = session.state_frame(220_000, -7, 0.5, 0.0)
    assert proto.decode_frame(frame[:-1])[2][:2] == (220_000, -7)


def test_device_session_rejects_other_protocol_versions():
    session = proto.DeviceSession(1000, 0.06)
    (reply,) = _hello(session, version=proto.PROTOCOL_VERSION + 1)
    assert proto.decode_frame(reply[:-1])[0::2] == (proto.MSG_ERROR, (proto.ERR_VERSION,))
    assert not session.session_open


def test_firmware_embeds_the_protocol_verbatim():
    assert FIRMWARE_PATH.exists()
    assert embedded_protocol() == PROTOCOL_PATH.read_text()
    ast.parse(FIRMWARE_PATH.read_text())  # the device program is valid Python


def test_protocol_module_is_micropython_friendly():
    tree = ast.parse(PROTOCOL_PATH.read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            imported.add(node.module or "")
    assert imported == {"struct"}  # no numpy, typing, dataclasses, __future__ on the brain

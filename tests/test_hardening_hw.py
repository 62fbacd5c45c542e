"""Hostile inputs on the hardware and vision side: torque limits, decoded values, handshakes, files, frames.

Each case is an input a broken or hostile device, camera or user can produce; the outcome must be a named
error or a legitimate result.  The fuzz tests at the end throw seeded random inputs at the frame decoder,
the handshake and the tracker and assert the outcome class of every one.
"""

from __future__ import annotations

import collections
import json
import math
import os
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
import serial

from softpend.hardware import protocol as proto
from softpend.hardware.driver import DeviceError, HandshakeError, LinkChecksumError, LinkDisconnected, MotorLink
from softpend.hardware.emulator import RigConfig, RigEmulator, SimRig
from softpend.vision.calibration import AffineCalibration, calibrate_from_markers
from softpend.vision.camera import SyntheticCamera, render_video
from softpend.vision.track_video import track_video
from softpend.vision.tracker import TipTracker

F32_MAX = struct.unpack("<f", struct.pack("<I", 0x7F7FFFFF))[0]


# ---------------------------------------------------------------------- a scripted device on a fake port
class FakeDevice:
    """A pyserial stand-in: a real :class:`~softpend.hardware.protocol.DeviceSession` answers the host's
    frames, unless ``hello_ack`` (``nonce -> HELLO_ACK values``) or ``hello_error`` (an ERROR code) replaces
    its answer to HELLO; :meth:`inject` queues arbitrary bytes for the host."""

    def __init__(self, torque_limit_nm=0.06, hello_ack=None, hello_error=None, torque_error=None):
        self.session = proto.DeviceSession(4096, torque_limit_nm, 100, 100)
        self.hello_ack = hello_ack
        self.hello_error = hello_error
        self.torque_error = torque_error
        self.inbox = bytearray()
        self.host_messages: list[tuple[int, int, tuple]] = []
        self._host_decoder = proto.FrameDecoder()
        self.timeout = 0.0
        self.now_us = 0

    # pyserial surface used by MotorLink
    def write(self, data: bytes) -> int:
        messages, errors = self._host_decoder.feed(data)
        assert not errors, errors  # the host never sends a broken frame
        for msg_type, seq, values in messages:
            self.host_messages.append((msg_type, seq, values))
            frame = proto.encode_message(msg_type, seq, values)
            if msg_type == proto.MSG_HELLO and self.hello_error is not None:
                self.inbox += proto.encode_message(proto.MSG_ERROR, seq, (self.hello_error,))
            elif msg_type == proto.MSG_HELLO and self.hello_ack is not None:
                self.inbox += proto.encode_message(proto.MSG_HELLO_ACK, seq, self.hello_ack(values[1]))
            elif msg_type == proto.MSG_TORQUE and self.torque_error is not None:
                self.inbox += proto.encode_message(proto.MSG_ERROR, seq, (self.torque_error,))
            else:
                for reply in self.session.receive(frame, self.now_us):
                    self.inbox += reply
        return len(data)

    def read(self, n: int = 1) -> bytes:
        out = bytes(self.inbox[:n])
        del self.inbox[:n]
        return out

    @property
    def in_waiting(self) -> int:
        return len(self.inbox)

    def flush(self) -> None:
        pass

    def close(self) -> None:
        pass

    # test helpers
    def inject(self, data: bytes) -> None:
        self.inbox += data

    def state(self, velocity=0.5, applied=0.0, flags=0, counts=10, seq=1) -> bytes:
        return proto.encode_message(proto.MSG_STATE, seq, (1000 * seq, counts, velocity, applied, 0, flags))

    def torques_on_wire(self) -> list[float]:
        return [v[0] for t, _, v in self.host_messages if t == proto.MSG_TORQUE]


@pytest.fixture
def fake_port(monkeypatch):
    """``fake_port(device) -> MotorLink`` opened on ``device`` (a :class:`FakeDevice`), not yet opened."""

    def make(device: FakeDevice, host_limit_nm: float = 0.06, **kwargs) -> MotorLink:
        monkeypatch.setattr(serial, "Serial", lambda *args, **kw: device)
        kwargs.setdefault("timeout_s", 0.05)
        return MotorLink("/dev/fake-softpend", torque_limit_nm=host_limit_nm, install_exit_hooks=False, **kwargs)

    return make


def _ack(cpr=4096, limit=0.06, watchdog_ms=100, rate_hz=100, version=proto.PROTOCOL_VERSION):
    return lambda nonce: (version, nonce, cpr, limit, watchdog_ms, rate_hz)


# ---------------------------------------------------------------------- torque limit
@pytest.mark.parametrize("device_limit", [-1.0, 0.0, math.nan, math.inf, -math.inf, 1e30, F32_MAX])
def test_invalid_device_torque_limit_is_refused_and_nothing_is_commanded(fake_port, device_limit):
    device = FakeDevice(hello_ack=_ack(limit=device_limit))
    link = fake_port(device)
    with pytest.raises(HandshakeError, match="torque_limit_nm"):
        link.open()
    assert not link.is_open
    with pytest.raises(LinkDisconnected):
        link.send_torque(0.05)
    assert device.torques_on_wire() == []  # -1 N m (the old clamp with the device's -1) never went out


def test_device_announcing_minus_one_over_the_twins_link_is_refused():
    rig = SimRig(RigConfig())
    rig.session.torque_limit_nm = -1.0  # a broken device program
    link = MotorLink("twin", 0.06, install_exit_hooks=False, serial=rig.connect())
    with pytest.raises(HandshakeError, match="torque_limit_nm must be in"):
        link.open()
    rig.clock.sleep_until(1.0)  # whatever the host sent on its way out has arrived
    assert rig.session.command_nm == 0.0 and rig.session.last_cmd_us is None


@pytest.mark.parametrize(
    "host_limit, device_limit, command",
    [
        (0.06, 0.04, 0.05),
        (0.06, 0.04, -0.05),
        (0.02, 0.06, 5.0),
        (0.06, 0.06, 5.0),
        (0.06, 0.06, -5.0),
        (0.06, 0.06, 0.06),
        (0.1, 0.06, 1e300),
        (0.05, 0.06, 1.0),
        (0.05, 0.06, -1.0),
        (0.07, 0.05, 0.2),
    ],
)
def test_torque_on_the_wire_never_exceeds_the_smaller_limit(fake_port, host_limit, device_limit, command):
    device = FakeDevice(torque_limit_nm=device_limit)
    with fake_port(device, host_limit) as link:
        link.send_torque(command)
        (wire,) = device.torques_on_wire()
    announced = struct.unpack("<f", struct.pack("<f", device_limit))[0]  # what HELLO_ACK carried
    assert abs(wire) <= min(host_limit, announced)  # as the float32 on the wire, not only before rounding
    assert math.copysign(1, wire) == math.copysign(1, command)
    assert abs(wire) == pytest.approx(min(host_limit, announced, abs(command)), rel=1e-6)
    assert not device.session.saturated or host_limit > announced  # the device never clamps our command


# ---------------------------------------------------------------------- handshake values
@pytest.mark.parametrize(
    "ack, field",
    [
        (_ack(cpr=0), "counts_per_rev"),
        (_ack(cpr=2**32 - 1), "counts_per_rev"),
        (_ack(rate_hz=0), "state_rate_hz"),
        (_ack(rate_hz=65535), "state_rate_hz"),
        (_ack(watchdog_ms=0), "watchdog_s"),
    ],
)
def test_impossible_hello_ack_is_a_named_handshake_error(fake_port, ack, field):
    link = fake_port(FakeDevice(hello_ack=ack))
    with pytest.raises(HandshakeError, match=f"impossible HELLO_ACK: {field}"):
        link.open()
    assert link.device is None and not link.is_open


def test_device_version_mismatch_says_what_it_means(fake_port):
    link = fake_port(FakeDevice(hello_error=proto.ERR_VERSION))
    with pytest.raises(HandshakeError, match="protocol version mismatch") as info:
        link.open()
    assert "error code 1" not in str(info.value) and "firmware" in str(info.value)
    with pytest.raises(HandshakeError, match="unknown error code 99"):
        fake_port(FakeDevice(hello_error=99)).open()


@pytest.mark.parametrize("torque", [math.nan, math.inf, "0.05", None, True, [0.1, 0.2]])
def test_a_torque_that_is_not_a_finite_number_stops_the_motor(fake_port, torque):
    device = FakeDevice()
    with fake_port(device) as link:
        link.send_torque(0.03)
        with pytest.raises(ValueError, match="torque_nm must be a finite number"):
            link.send_torque(torque)
        assert device.torques_on_wire() == [pytest.approx(0.03)]
        assert device.host_messages[-1][0] == proto.MSG_STOP and device.session.stopped


def test_device_error_after_the_handshake_is_explained(fake_port):
    device = FakeDevice(torque_error=proto.ERR_NO_SESSION)
    with fake_port(device) as link:
        link.send_torque(0.01)
        with pytest.raises(DeviceError, match="no session open"):
            link.read_state()


# ---------------------------------------------------------------------- decoded STATE values
@pytest.mark.parametrize(
    "bad",
    [
        dict(velocity=math.nan),
        dict(velocity=math.inf),
        dict(velocity=-1e6),
        dict(applied=math.nan),
        dict(applied=-math.inf),
        dict(applied=0.5),
        dict(flags=0x80),
    ],
    ids=[
        "nan_velocity",
        "inf_velocity",
        "huge_velocity",
        "nan_torque",
        "inf_torque",
        "torque_over_limit",
        "undefined_flag",
    ],
)
def test_state_with_impossible_values_is_rejected_and_counted(fake_port, bad):
    device = FakeDevice()
    with fake_port(device) as link:
        device.inject(device.state(seq=1, **bad) + device.state(seq=2, velocity=0.25, applied=0.01))
        state = link.read_state()
        assert state.seq == 2 and state.phi_dot_rad_s == 0.25  # the bad one was never passed on
        assert link._decoder.value_errors == 1 and link.bad_frames == 1
        device.inject(device.state(seq=3, **bad) * 3)
        with pytest.raises(LinkChecksumError, match="refused"):
            link.read_state()
    assert device.host_messages[-1][0] == proto.MSG_STOP


# ---------------------------------------------------------------------- files: rig --port, twin workdir
def test_rig_port_never_replaces_a_regular_file_a_folder_or_a_foreign_symlink(tmp_path):
    from softpend.cli import main

    precious = tmp_path / "ttyRIG"
    precious.write_text("user data\n")
    with pytest.raises(ValueError, match="existing file"):
        RigEmulator(RigConfig(), link_path=precious)
    assert main(["rig", "--port", str(precious), "--duration", "0.05"]) == 2
    assert precious.read_text() == "user data\n"
    folder = tmp_path / "folder"
    folder.mkdir()
    with pytest.raises(ValueError, match="existing folder"):
        RigEmulator(RigConfig(), link_path=folder)
    link = tmp_path / "to_file"
    link.symlink_to(precious)
    with pytest.raises(ValueError, match="not to a pseudo-terminal"):
        RigEmulator(RigConfig(), link_path=link)
    assert os.readlink(link) == str(precious) and precious.read_text() == "user data\n"


def test_rig_port_replaces_a_stale_pty_symlink_and_removes_only_its_own(tmp_path):
    path = tmp_path / "ttyRIG"
    path.symlink_to("/dev/pts/987654")  # left behind by a killed emulator
    emulator = RigEmulator(RigConfig(), link_path=path)
    try:
        assert os.readlink(path) == emulator.port
    finally:
        emulator.close()
    assert not path.is_symlink()
    emulator = RigEmulator(RigConfig(), link_path=path)
    path.unlink()
    path.write_text("made by someone else meanwhile\n")
    emulator.close()  # the path no longer is this emulator's symlink: left alone
    assert path.read_text() == "made by someone else meanwhile\n"


def test_twin_refuses_a_foreign_file_in_its_workdir_and_touches_nothing(tmp_path):
    from softpend.hardware.twin import run_twin_session

    (tmp_path / "motor_log.csv").write_text("my own log\n")
    with pytest.raises(ValueError, match="not a file this command wrote"):
        run_twin_session(tmp_path, duration_s=7.0, trial_length_s=2.0, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["motor_log.csv"]
    assert (tmp_path / "motor_log.csv").read_text() == "my own log\n"
    with pytest.raises(ValueError, match="not a folder"):
        run_twin_session(tmp_path / "motor_log.csv", duration_s=7.0, trial_length_s=2.0, progress=False)


# ---------------------------------------------------------------------- files: track
@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    """A 12-frame video of a still rod with its sidecar."""
    from softpend.plant import RodParams, make_plant

    plant = make_plant("prb", params=RodParams())
    q, qd = plant.hanging_state()
    q[0] = 2.5
    plant.reset(q, qd)
    times = np.arange(3) * 0.055
    points = np.stack([plant.link_points_m()] * 3)
    hub = np.full(3, 2.5)
    video = tmp_path_factory.mktemp("clip") / "clip.avi"
    render_video(video, SyntheticCamera(seed=5), times, points, hub, fps=100.0)
    return video


def test_track_checks_inputs_before_touching_the_output(tmp_path, capsys):
    from softpend.cli import main

    out = tmp_path / "existing.csv"
    out.write_text("results I want to keep\n")
    assert main(["track", str(tmp_path / "missing.avi"), "--out", str(out)]) == 2
    assert out.read_text() == "results I want to keep\n"
    assert main(["track", str(tmp_path / "missing.avi"), "--out", str(tmp_path / "nofolder" / "x.csv")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["track", str(tmp_path / "missing.avi"), "--out", str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["existing.csv"]


def test_track_failing_mid_video_leaves_the_output_and_no_partial_file(tmp_path, clip):
    from softpend.io.samplelog import read_sample_log

    short = tmp_path / "short" / "clip.avi"  # a sidecar with too few timestamps: tracking fails at frame 3
    short.parent.mkdir()
    shutil.copyfile(clip, short)
    sidecar = json.loads(Path(f"{clip}.json").read_text()) | {"timestamps_s": [0.0, 0.01, 0.02]}
    Path(f"{short}.json").write_text(json.dumps(sidecar))
    out = tmp_path / "out" / "existing.csv"
    out.parent.mkdir()
    out.write_text("results I want to keep\n")
    with pytest.raises(ValueError, match="timestamps_s has 3 entries"):
        track_video(short, out)
    assert out.read_text() == "results I want to keep\n"
    assert sorted(p.name for p in out.parent.iterdir()) == ["existing.csv"]
    rows = track_video(clip, out)  # a whole video tracked: only now is the output replaced
    assert len(read_sample_log(out)) == len(rows) == 12
    assert sorted(p.name for p in out.parent.iterdir()) == ["existing.csv"]


@pytest.mark.parametrize("fps", ["inf", "0", "nan", "-5", "1e300"])
def test_track_refuses_an_impossible_frame_rate(tmp_path, clip, fps, capsys):
    from softpend.cli import main

    out = tmp_path / "out.csv"
    assert main(["track", str(clip), "--out", str(out), "--fps", fps]) == 2
    assert (
        "--fps must lie in" in capsys.readouterr().err and not out.exists()
    )  # refused by name before the video is opened
    with pytest.raises(ValueError, match="fps must be"):
        track_video(tmp_path / "missing.avi", out, fps=float(fps))


@pytest.mark.parametrize(
    "sidecar, field",
    [
        ([1, 2, 3], "JSON object"),
        ({"fps": "fast"}, "fps"),
        ({"fps": math.inf}, "fps"),
        ({"fps": 0}, "fps"),
        ({"timestamps_s": [0.0, None]}, "timestamps_s"),
        ({"timestamps_s": "0.0"}, "timestamps_s"),
        ({"markers_m": "abc"}, "markers_m"),
        ({"markers_m": [[0, 1], [2]]}, "markers_m"),
        ({"markers_m": [[0, 1], [2, 3]]}, "markers_m"),
        ({"markers_m": [[0, 1], [2, 3], [math.nan, 1]]}, "markers_m"),
        ("[" * 100000, "not valid JSON"),
        ("{bad json", "not valid JSON"),
    ],
)
def test_malformed_sidecar_is_a_named_error(tmp_path, clip, sidecar, field):
    video = tmp_path / "clip.avi"
    video.write_bytes(clip.read_bytes())
    good = json.loads((clip.parent / "clip.avi.json").read_text())
    if isinstance(sidecar, dict):
        text = json.dumps({**good, **sidecar}, allow_nan=True)
    elif isinstance(sidecar, str):
        text = sidecar
    else:
        text = json.dumps(sidecar)
    (tmp_path / "clip.avi.json").write_text(text)
    with pytest.raises(ValueError, match=f"sidecar .*{field}"):
        track_video(video, tmp_path / "out.csv")
    assert not (tmp_path / "out.csv").exists()


@pytest.mark.parametrize(
    "content, field",
    [
        ("[]", "JSON object"),
        ('{"pixel_to_metre": [[1, 2], [3]]}', "pixel_to_metre"),
        ('{"pixel_to_metre": "abc"}', "pixel_to_metre"),
        ('{"pixel_to_metre": [[1, 0, 0], [0, 1]]}', "pixel_to_metre"),
        ('{"pixel_to_metre": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}', "pixel_to_metre"),
        ('{"pixel_to_metre": [[1, 0, 0], [0, 1, 0]], "residual_rms_m": "x"}', "residual_rms_m"),
        ('{"pixel_to_metre": [[1, 0, 0], [0, 1, 0]], "residual_rms_m": -1}', "residual_rms_m"),
        ('{"pixel_to_metre": [[1, 0, 0], [0, 1, 0]], "extra": 1}', "unknown keys"),
        ("{}", "pixel_to_metre"),
        ("not json", "not valid JSON"),
        ("[" * 100000, "not valid JSON"),
    ],
)
def test_malformed_calibration_file_is_a_named_error(tmp_path, content, field, capsys):
    from softpend.cli import main

    path = tmp_path / "calibration.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=f"calibration.*{field}"):
        AffineCalibration.load(path)
    assert main(["track", str(tmp_path / "v.avi"), "--out", str(tmp_path / "o.csv"), "--calibration", str(path)]) == 2
    assert "calibration" in capsys.readouterr().err


def test_calibration_round_trip_and_bad_markers():
    calibration = AffineCalibration(np.array([[0.002, 0.0, -0.6], [0.0, -0.002, 0.5]]), 1e-4)
    again = AffineCalibration.from_data(json.loads(calibration.to_json()))
    np.testing.assert_array_equal(again.pixel_to_metre, calibration.pixel_to_metre)
    frame = np.zeros((32, 32, 3), np.uint8)
    for markers in ("abc", [[0, 1], [2]], {"a": 1}, [[0, 1], [1, 0], [math.inf, 0]], [[0, 1]] * 7):
        with pytest.raises(ValueError, match="marker_positions_m"):
            calibrate_from_markers(frame, markers)


# ---------------------------------------------------------------------- frames
_TIP_BGR = (200, 70, 20)


def test_a_frame_full_of_blue_is_no_tip():
    blue = np.zeros((480, 640, 3), np.uint8)
    blue[:] = _TIP_BGR
    d = TipTracker().track(blue)
    assert d.lost and math.isnan(d.x_px) and math.isnan(d.y_px)
    half = np.full((480, 640, 3), 210, np.uint8)
    half[:, :320] = _TIP_BGR
    assert TipTracker().track(half).lost
    # a tracker that found the dot, then sees blue everywhere: the search window is all blue, the frame too
    camera = SyntheticCamera(seed=0)
    frame, tip = camera.draw(np.array([[0.0, 0.0], [0.1, -0.1], [0.2, -0.25]]))
    tracker = TipTracker()
    assert tracker.track(frame).x_px == pytest.approx(tip[0], abs=0.5)
    assert tracker.track(blue).lost
    assert tracker.track(frame).x_px == pytest.approx(tip[0], abs=0.5)  # and recovers
    # a region tracker whose region is flooded with magenta reports no marker (not the region's centre)
    from softpend.vision.tracker import MAGENTA_HSV

    magenta = np.full((100, 100, 3), (180, 0, 220), np.uint8)
    assert TipTracker(MAGENTA_HSV, min_area_px=6.0, region_px=(40, 40, 60, 60)).track(magenta).lost


@pytest.mark.parametrize(
    "frame",
    [
        np.zeros((0, 0, 3), np.uint8),
        np.zeros((0, 5, 3), np.uint8),
        np.zeros((4, 4, 3), np.uint8),
        np.zeros((1, 640, 3), np.uint8),
        np.zeros((20, 20, 3), np.float32),
        np.zeros((20, 20, 3), bool),
        np.zeros((20, 20, 3), np.uint16),
        np.zeros((20, 20), np.uint8),
        np.zeros((20, 20, 4), np.uint8),
        np.zeros((2, 20, 20, 3), np.uint8),
        [[[0, 0, 0]] * 20] * 20,
        None,
    ],
    ids=["empty", "zero_rows", "4x4", "one_row", "float32", "bool", "uint16", "gray", "bgra", "4d", "list", "none"],
)
def test_bad_frames_are_a_named_value_error(frame):
    with pytest.raises(ValueError, match="frame_bgr"):
        TipTracker().track(frame)
    from softpend.vision.tracker import GREEN_HSV, find_blobs

    with pytest.raises(ValueError, match="frame_bgr"):
        find_blobs(frame, GREEN_HSV)


def test_bad_tracker_settings_are_named():
    for kwargs, name in [
        (dict(search_radius_px=math.inf), "search_radius_px"),
        (dict(min_area_px="5"), "min_area_px"),
        (dict(min_area_px=math.nan), "min_area_px"),
        (dict(region_px=(1, 2, 3)), "region_px"),
        (dict(region_px=(0, 0, math.nan, 5)), "region_px"),
        (dict(colour="blue"), "colour"),
    ]:
        with pytest.raises(ValueError, match=name):
            TipTracker(**kwargs)
    with pytest.raises(ValueError, match="region_px .* outside"):
        TipTracker(region_px=(700, 0, 800, 10)).track(np.zeros((480, 640, 3), np.uint8))


# ---------------------------------------------------------------------- fuzz
def _random_value(rng: np.random.Generator) -> float:
    specials = [math.nan, math.inf, -math.inf, 0.0, -0.0, F32_MAX, -F32_MAX, 1e-40, 1e30, -1.0]
    if rng.random() < 0.3:
        return specials[rng.integers(len(specials))]
    return float(np.float32(rng.normal(0, 10 ** rng.uniform(-3, 4))))


def _random_chunk(rng: np.random.Generator, device: FakeDevice) -> bytes:
    kind = rng.integers(5)
    if kind == 0:  # random bytes, zeros included
        return bytes(rng.integers(0, 256, size=int(rng.integers(1, 120)), dtype=np.uint8))
    if kind == 1:  # a valid-CRC STATE with random values
        return device.state(
            velocity=_random_value(rng),
            applied=_random_value(rng),
            flags=int(rng.integers(0, 256)),
            counts=int(rng.integers(-(2**31), 2**31)),
            seq=int(rng.integers(0, 65536)),
        )
    if kind == 2:  # a good STATE, one bit flipped
        frame = bytearray(device.state(velocity=float(rng.normal()), applied=0.01))
        i = int(rng.integers(0, len(frame)))
        frame[i] ^= 1 << int(rng.integers(0, 8))
        return bytes(frame)
    if kind == 3:  # any message type with a valid CRC and random body bytes
        msg_type = int(rng.choice(list(proto.MESSAGE_FORMATS)))
        size = struct.calcsize(proto.MESSAGE_FORMATS[msg_type])
        payload = struct.pack(proto.HEADER_FORMAT, msg_type, int(rng.integers(0, 65536)))
        payload += bytes(rng.integers(0, 256, size=size, dtype=np.uint8))
        crc = proto.crc16_ccitt(payload)
        return proto.cobs_encode(payload + bytes(((crc >> 8) & 0xFF, crc & 0xFF))) + b"\x00"
    return device.state(velocity=float(rng.normal()), applied=float(rng.uniform(-0.06, 0.06)))  # a good one


def _limits_ok(link: MotorLink, state) -> bool:
    return (
        math.isfinite(state.phi_rad)
        and math.isfinite(state.phi_dot_rad_s)
        and math.isfinite(state.device_time_s)
        and abs(state.applied_torque_nm) <= link.device.torque_limit_nm * (1 + 1e-6)
        and not state.flags & ~proto.FLAG_MASK
    )


def test_fuzz_decoder_never_passes_on_an_impossible_state(fake_port):
    rng = np.random.default_rng(20240518)
    outcomes = collections.Counter()
    device = FakeDevice()
    link = fake_port(device).open()
    n_chunks = 20000
    for _ in range(n_chunks):
        device.inject(_random_chunk(rng, device))
        try:
            states = link.drain_states()
        except LinkChecksumError:
            outcomes["LinkChecksumError"] += 1
            link._decoder.consecutive_bad = 0
            continue
        except DeviceError:
            outcomes["DeviceError"] += 1  # a random valid ERROR frame
            continue
        for state in states:
            assert _limits_ok(link, state), state
        outcomes["states" if states else "nothing"] += 1
    link.close()
    print(
        f"decoder fuzz: {n_chunks} chunks, {dict(outcomes)}, rejected values {link._decoder.value_errors}, "
        f"bad frames {link.bad_frames}"
    )
    assert sum(outcomes.values()) == n_chunks
    assert outcomes["states"] > 100 and link._decoder.value_errors > 100 and outcomes["LinkChecksumError"] > 0


def test_fuzz_handshake_values_and_torque_on_the_wire(fake_port):
    rng = np.random.default_rng(7)
    outcomes = collections.Counter()
    n_cases = 3000
    for _ in range(n_cases):  # each field plausible about 3 times in 4, so both outcomes are common
        cpr = int(rng.choice([0, 4096, 4096, int(rng.integers(1, 1 << 16)), int(rng.integers(0, 2**32))]))
        limit = _random_value(rng) if rng.random() < 0.4 else float(np.float32(rng.uniform(0.001, 2)))
        watchdog = int(rng.choice([0, 100, 100, int(rng.integers(0, 65536))]))
        rate = int(rng.choice([0, 100, int(rng.integers(1, 10001)), int(rng.integers(0, 65536))]))
        host = float(rng.uniform(0.001, 1.0))
        device = FakeDevice(hello_ack=_ack(cpr, limit, watchdog, rate))
        link = fake_port(device, host)
        try:
            link.open()
        except HandshakeError as exc:
            assert "impossible HELLO_ACK" in str(exc)
            assert device.torques_on_wire() == []
            outcomes["HandshakeError"] += 1
            continue
        info = link.device
        assert 1 <= info.counts_per_rev <= 1 << 24 and 0 < info.torque_limit_nm <= 1000
        assert info.watchdog_s > 0 and 1 <= info.state_rate_hz <= 10000
        for command in (float(rng.normal(0, 10)), 1e300, -1e300, host, -info.torque_limit_nm):
            link.send_torque(command)
        assert all(abs(t) <= min(host, info.torque_limit_nm) for t in device.torques_on_wire())
        link.close()
        outcomes["accepted"] += 1
    print(f"handshake fuzz: {n_cases} cases, {dict(outcomes)}")
    assert sum(outcomes.values()) == n_cases and outcomes["accepted"] > 100 and outcomes["HandshakeError"] > 100


def _random_frame(rng: np.random.Generator):
    kind = rng.integers(10)
    if kind == 0:  # wrong type, dtype or shape
        shape = tuple(int(v) for v in rng.integers(0, 24, size=int(rng.integers(1, 5))))
        dtype = [np.uint8, np.float32, np.int16, bool, np.float64][int(rng.integers(5))]
        return np.zeros(shape, dtype)
    h, w = int(rng.integers(0, 120)), int(rng.integers(0, 160))
    if kind == 1:  # random noise, any size (empty and undersized included)
        return rng.integers(0, 256, size=(h, w, 3), dtype=np.uint8)
    frame = np.full((h, w, 3), rng.integers(0, 256, size=3, dtype=np.uint8), np.uint8)  # one colour
    for _ in range(int(rng.integers(0, 4))):  # blue rectangles of any size
        if h and w:
            y0, x0 = int(rng.integers(0, h)), int(rng.integers(0, w))
            frame[y0 : y0 + int(rng.integers(1, h + 1)), x0 : x0 + int(rng.integers(1, w + 1))] = _TIP_BGR
    return frame


def test_fuzz_tracker_outcome_classes():
    rng = np.random.default_rng(11)
    outcomes = collections.Counter()
    trackers = [
        TipTracker(),
        TipTracker(min_area_px=0.0),
        TipTracker(search_radius_px=None),
        TipTracker(region_px=(10, 10, 60, 50), min_area_px=4.0),
    ]
    n_frames = 5000
    for k in range(n_frames):
        frame = _random_frame(rng)
        tracker = trackers[k % len(trackers)]
        try:
            d = tracker.track(frame)
        except ValueError as exc:
            assert "frame_bgr" in str(exc) or "region_px" in str(exc), exc
            outcomes["ValueError"] += 1
            continue
        h, w = frame.shape[:2]
        if d.lost:
            assert math.isnan(d.x_px) and math.isnan(d.y_px)
            outcomes["lost"] += 1
        else:
            assert 0 <= d.x_px <= w and 0 <= d.y_px <= h
            assert tracker.min_area_px <= d.area_px <= 0.05 * h * w
            outcomes["tip"] += 1
    print(f"tracker fuzz: {n_frames} frames, {dict(outcomes)}")
    assert sum(outcomes.values()) == n_frames and min(outcomes.values()) > 50


def _random_json(rng: np.random.Generator, depth: int = 0):
    kind = int(rng.integers(9 if depth < 4 else 6))
    if kind == 0:
        return None
    if kind == 1:
        return bool(rng.integers(2))
    if kind == 2:
        return int(rng.integers(-10, 10))
    if kind == 3:
        return [math.nan, math.inf, -1.0, 0.0, 1e300, float(rng.normal())][int(rng.integers(6))]
    if kind == 4:
        return "abc"
    if kind == 5:
        return float(rng.normal())
    if kind == 6:
        return [_random_json(rng, depth + 1) for _ in range(int(rng.integers(0, 4)))]
    if kind == 7:  # a matrix or point list of random size, sometimes right
        rows, cols = int(rng.integers(0, 8)), int(rng.integers(1, 4))
        return rng.normal(size=(rows, cols)).tolist()
    keys = ["pixel_to_metre", "residual_rms_m", "fps", "timestamps_s", "markers_m", "other"]
    return {
        keys[int(i)]: _random_json(rng, depth + 1) for i in rng.integers(0, len(keys), size=int(rng.integers(0, 4)))
    }


def test_fuzz_calibration_and_sidecar_contents():
    from softpend.vision.camera import check_sidecar

    rng = np.random.default_rng(3)
    outcomes = collections.Counter()
    n_cases = 3000
    for k in range(n_cases):
        data = _random_json(rng)
        if k % 3 == 0:  # often a nearly right calibration
            data = {
                "pixel_to_metre": rng.normal(size=(2, int(rng.integers(2, 5)))).tolist(),
                "residual_rms_m": _random_json(rng, 4) if rng.random() < 0.5 else 0.001,
            }
        elif k % 3 == 1 and isinstance(data, dict):  # ... or a nearly right sidecar
            data["markers_m"] = rng.normal(size=(int(rng.integers(2, 8)), 2)).tolist()
        text = json.dumps(data, allow_nan=True)
        try:
            calibration = AffineCalibration.from_data(json.loads(text))
            assert np.all(np.isfinite(calibration.pixel_to_metre)) and calibration.residual_rms_m >= 0
            outcomes["calibration"] += 1
        except ValueError:
            outcomes["calibration ValueError"] += 1
        try:
            checked = check_sidecar(json.loads(text))
            assert checked.get("fps") is None or 0 < checked["fps"] <= 1e6
            assert all(math.isfinite(t) for t in checked.get("timestamps_s") or [])
            assert checked.get("markers_m") is None or 3 <= len(checked["markers_m"]) <= 6
            outcomes["sidecar"] += 1
        except ValueError:
            outcomes["sidecar ValueError"] += 1
    print(f"calibration/sidecar fuzz: {n_cases} documents, {dict(outcomes)}")
    assert sum(outcomes.values()) == 2 * n_cases and min(outcomes.values()) > 50

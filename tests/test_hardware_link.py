"""The motor link end to end: round trip, safety and every fault.

The device is the twin's (:class:`~softpend.hardware.emulator.SimRig`: the protocol bytes over an in-memory
link, in simulated time) and the host the real :class:`MotorLink`; the real I/O path -- a pseudo-terminal, the
emulator in a process or thread of its own, a host process that gets SIGTERM -- is covered by a few real-time
smoke tests (marker ``realtime``) that check behaviour, never a timing figure.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from softpend.hardware import protocol as proto
from softpend.hardware.closed_loop import LOOP_LOG_COLUMNS, run_control_loop
from softpend.hardware.driver import HandshakeError, LinkChecksumError, LinkDisconnected, LinkTimeout, MotorLink
from softpend.hardware.emulator import EmulatorProcess, RigConfig, RigEmulator, SimRig
from softpend.io.samplelog import SampleLog, read_sample_log


class ThreadedRig:
    """A RigEmulator served from a thread (a real pty, the same code as the process)."""

    def __init__(self, **config):
        self.emulator = RigEmulator(RigConfig(**config))
        self.thread = threading.Thread(target=self.emulator.serve, daemon=True)
        self.thread.start()

    @property
    def port(self) -> str:
        return self.emulator.port

    def close(self):
        self.emulator.stop()
        self.thread.join(2.0)
        self.emulator.close()


def link_to(r: SimRig, torque_limit_nm: float = 0.06, **kwargs) -> MotorLink:
    """A MotorLink (not yet opened) on the twin's in-memory link to ``r``."""
    return MotorLink("twin", torque_limit_nm=torque_limit_nm, install_exit_hooks=False, serial=r.connect(), **kwargs)


def eventually(r: SimRig, predicate, timeout_s: float = 2.0) -> bool:
    """Run the twin's clock until ``predicate`` holds or ``timeout_s`` of simulated time passes."""
    return r.clock.wait_for(predicate, r.clock.now_s() + timeout_s)


def applied_now(link: MotorLink) -> float:
    """The applied torque in the newest STATE frame received [N m] (NaN when none arrived)."""
    states = link.drain_states()
    return states[-1].applied_torque_nm if states else math.nan


@pytest.fixture
def rig():
    return lambda **config: SimRig(RigConfig(**config))


def test_round_trip_handshake_states_and_encoder(rig):
    r = rig(counts_per_rev=512, latency_s=0.001)
    with link_to(r) as link:
        assert link.device.protocol_version == proto.PROTOCOL_VERSION
        assert link.device.counts_per_rev == 512 and link.device.watchdog_s == pytest.approx(0.1)
        assert 0 < link.ping() < 0.1
        states = []
        for _ in range(40):
            states.append(link.read_state())
            link.send_torque(0.05)
        t = np.array([s.device_time_s for s in states])
        assert np.median(np.diff(t)) == pytest.approx(0.01, abs=0.002)
        # the applied torque follows the command after the link latency, and the hub turns that way
        assert states[-1].applied_torque_nm == pytest.approx(0.05, rel=1e-6)
        assert states[-1].phi_rad > states[0].phi_rad + 0.01
        # quantised encoder: phi = pi + counts * 2 pi / cpr exactly
        counts = (np.array([s.phi_rad for s in states]) - math.pi) / (2 * math.pi / 512)
        np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
        assert states[-1].last_cmd_seq > 0 and not states[-1].watchdog_tripped


def test_torque_is_clamped_on_the_host_and_nan_stops(rig):
    r = rig()
    with link_to(r, 0.02) as link:
        assert link.torque_limit_nm == pytest.approx(0.02)
        link.read_state()
        link.send_torque(5.0)
        assert link.last_command_nm == pytest.approx(0.02)
        assert eventually(r, lambda: applied_now(link) == pytest.approx(0.02, rel=1e-6))
        assert not link.read_state().flags & proto.FLAG_SATURATED  # the device never saw more than its limit
        with pytest.raises(ValueError, match="torque_nm"):
            link.send_torque(float("nan"))
        assert eventually(r, lambda: r.session.torque_nm(0) == 0.0 and r.session.stopped)


def test_stalled_host_trips_the_watchdog(rig):
    r = rig(watchdog_ms=100)
    with link_to(r) as link:
        for _ in range(10):
            link.read_state()
            link.send_torque(0.04)
        stall_start = link.read_state().device_time_s
        r.clock.sleep_until(r.clock.now_s() + 0.35)  # the host hangs: no commands
        states = link.drain_states()
        late = [s for s in states if s.device_time_s > stall_start + 0.13]
        early = [s for s in states if s.device_time_s < stall_start + 0.08]
        assert early and all(s.applied_torque_nm == pytest.approx(0.04) for s in early)
        assert late and all(s.applied_torque_nm == 0.0 and s.watchdog_tripped for s in late)
        link.send_torque(0.01)  # commands resume: so does the torque
        assert eventually(r, lambda: applied_now(link) == pytest.approx(0.01))


def test_garbled_link_raises_clear_error_and_stops_motor(rig):
    r = rig(garble_probability=1.0)
    link = link_to(r)
    link.open()  # the handshake reply is not garbled (only STATE frames are)
    link.send_torque(0.03)
    with pytest.raises(LinkChecksumError, match="3 consecutive bad frames.*motor stopped"):
        for _ in range(10):
            link.read_state()
    assert eventually(r, lambda: r.session.stopped and r.session.torque_nm(0) == 0.0)
    link.close()


def test_isolated_garbled_frames_are_counted_not_fatal(rig, tmp_path):
    r = rig(garble_probability=0.15, drop_probability=0.1, seed=3)
    link = link_to(r)
    link.max_consecutive_bad_frames = 4
    with link, SampleLog(tmp_path / "log.csv", LOOP_LOG_COLUMNS) as log:
        result = run_control_loop(link, lambda obs, t: 0.01, duration_s=0.6, log=log)
    assert result.bad_frames > 0 and result.dropped_states > 0
    assert len(read_sample_log(tmp_path / "log.csv")) == result.samples


def test_controller_exception_stops_motor_and_keeps_samples(rig, tmp_path):
    r = rig()
    calls = []

    def controller(obs, t):
        calls.append(t)
        if len(calls) == 20:
            raise RuntimeError("controller bug")
        return 0.04

    with link_to(r) as link, SampleLog(tmp_path / "log.csv", LOOP_LOG_COLUMNS) as log:
        with pytest.raises(RuntimeError, match="controller bug"):
            run_control_loop(link, controller, duration_s=2.0, log=log)
        assert eventually(r, lambda: r.session.stopped)  # STOP went out before the exception left the loop
    data = read_sample_log(tmp_path / "log.csv")
    assert len(data) == 20 and data["command_torque_nm"][-1] == 0.0


def test_handshake_timeout_when_nothing_answers():
    master, slave = os.openpty()
    try:
        link = MotorLink(os.ttyname(slave), torque_limit_nm=0.06, timeout_s=0.15, install_exit_hooks=False)
        with pytest.raises(HandshakeError, match="no HELLO_ACK"):
            link.open()
        assert not link.is_open
    finally:
        os.close(master)
        os.close(slave)


def test_missing_port_is_a_clear_disconnect():
    with pytest.raises(LinkDisconnected, match="cannot open serial port"):
        MotorLink("/dev/does-not-exist-softpend", torque_limit_nm=0.06, install_exit_hooks=False).open()
    with pytest.raises(ValueError, match="torque_limit_nm"):
        MotorLink("/dev/null", torque_limit_nm=-1.0)


@pytest.mark.realtime
def test_killed_emulator_is_a_clear_disconnect_and_no_sample_is_lost(tmp_path):
    calls = []
    with EmulatorProcess(RigConfig(), truth_log=tmp_path / "truth.csv") as emulator:
        with (
            MotorLink(emulator.port, torque_limit_nm=0.06, install_exit_hooks=False) as link,
            SampleLog(tmp_path / "motor.csv", LOOP_LOG_COLUMNS) as log,
        ):
            killer = threading.Timer(0.5, emulator.kill)
            killer.start()

            def controller(obs, t):
                calls.append(t)
                return 0.02

            with pytest.raises((LinkDisconnected, LinkTimeout), match="disconnected|no STATE"):
                run_control_loop(link, controller, duration_s=5.0, log=log)
            killer.join()
    motor = read_sample_log(tmp_path / "motor.csv")
    assert len(motor) == len(calls) > 20  # every sample the host processed is on disk
    truth = read_sample_log(tmp_path / "truth.csv")  # the SIGKILLed emulator's log is readable too
    assert len(truth) >= len(motor) and truth.torn_lines == 0
    assert np.all(np.diff(truth["device_time_s"]) > 0)


_HOST_SCRIPT = """
import sys, time
from softpend.hardware.driver import MotorLink
link = MotorLink(sys.argv[1], torque_limit_nm=0.06).open()
link.read_state()
link.send_torque(0.05)
print("commanding", flush=True)
while True:  # keep commanding until SIGTERM
    link.read_state()
    link.send_torque(0.05)
"""


# The signal lands while the host's main thread is inside its own frame write (holding the write lock):
# the handler must neither deadlock on the lock nor cut the frame in two.
_HOST_SCRIPT_SIGNAL_MID_WRITE = """
import os, signal, sys
from softpend.hardware import driver
from softpend.hardware.driver import MotorLink
link = MotorLink(sys.argv[1], torque_limit_nm=0.06).open()
link.read_state()
link.send_torque(0.05)
print("commanding", flush=True)
sys.stdin.readline()
write = driver._write_frame
def write_then_signal(ser, frame, timeout_s):  # the next write is interrupted by SIGTERM, once
    driver._write_frame = write
    os.kill(os.getpid(), signal.SIGTERM)
    return write(ser, frame, timeout_s)
driver._write_frame = write_then_signal
link.send_torque(0.05)
print("not reached", flush=True)
"""


@pytest.mark.realtime
@pytest.mark.parametrize("script", [_HOST_SCRIPT, _HOST_SCRIPT_SIGNAL_MID_WRITE], ids=["loop", "mid_write"])
def test_sigterm_on_the_host_sends_stop(script):
    r = ThreadedRig(watchdog_ms=5000)  # a long watchdog: only the host's own STOP can zero the torque quickly
    host = subprocess.Popen(
        [sys.executable, "-c", script, r.port], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    session = r.emulator.session

    def within(predicate, timeout_s: float = 60.0) -> bool:  # a guard against a hang on a loaded machine
        deadline = time.monotonic() + timeout_s
        while not predicate() and time.monotonic() < deadline:
            time.sleep(0.01)
        return predicate()

    try:
        assert host.stdout.readline().strip() == "commanding"
        assert within(lambda: session.torque_nm(0) == pytest.approx(0.05))
        if script is _HOST_SCRIPT:
            host.send_signal(signal.SIGTERM)
        else:
            host.stdin.write("go\n")
            host.stdin.flush()
        assert host.wait(60) == 128 + signal.SIGTERM
        assert host.stdout.read() == ""
        assert within(lambda: session.stopped) and session.torque_nm(0) == 0.0
        assert session.decoder.bad_frames == 0  # no frame was cut in two by the STOP
    finally:
        if host.poll() is None:
            host.kill()
        host.stdout.close()
        host.stdin.close()
        r.close()


def test_a_host_scheduled_after_its_deadline_still_takes_the_state_that_arrived(rig):
    """The host asks for a state with a deadline already past (it was not scheduled in time): the states that
    arrived meanwhile are read and returned, not reported as a silent link."""
    r = rig()
    with link_to(r) as link:
        link.drain_states()
        r.clock.sleep_until(r.clock.now_s() + 0.05)  # states arrive in the port, unread
        message = link._next_message(r.clock.now_s() - 1.0, (proto.MSG_STATE,))
        assert message[0] == proto.MSG_STATE
        link.drain_states()
        r.host = None  # now the device sends nothing: the same call times out
        r.clock.sleep_until(r.clock.now_s() + 0.05)
        link.drain_states()
        with pytest.raises(LinkTimeout, match="no STATE"):
            link._next_message(r.clock.now_s() - 1.0, (proto.MSG_STATE,))
